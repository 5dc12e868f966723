//! COPC inputs (issue 42): `fixtures/autzen_trim.copc.laz`, written by
//! `copc_converter` from `fixtures/autzen_trim.laz`. A conversion by region
//! (`--bounds`, `--clip`) holds exactly the LAZ's points inside it (read by the
//! `las` crate), read from the local file, from a `python3 -m http.server` and
//! from SeaweedFS (`weed mini`) over S3, whose request counts show that only
//! the nodes reaching the region were fetched. Bad COPC files are errors that
//! name the file and byte offset; mutated ones never panic. With CI=true a
//! missing python3 or weed is a failure, else a skip.

mod common;

use common::cli::{err, info_json, ok, pcimg};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// The LAZ's points inside the box `lo`..`hi` (every point: `None`).
fn laz_points_inside(lo: [f64; 3], hi: [f64; 3]) -> u64 {
    let mut r = las::Reader::from_path(fixture("autzen_trim.laz")).unwrap();
    r.read_all()
        .unwrap()
        .points()
        .filter(|p| {
            let p = p.as_ref().unwrap();
            let v = [p.x, p.y, p.z];
            (0..3).all(|a| v[a] >= lo[a] && v[a] <= hi[a])
        })
        .count() as u64
}

/// The points of the dataset at `out`.
fn points(out: &Path) -> u64 {
    let o = pcimg().arg("info").arg("--json").arg(out).output().unwrap();
    info_json(&ok(&o, "info"))["points"].as_u64().unwrap()
}

/// `pcimg convert INPUT -o OUT EXTRA…` (stderr kept for the caller).
fn convert(input: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    pcimg()
        .args(["convert", input, "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// `pcimg: network: N requests, B bytes received` of `--net-stats`.
fn network(stderr: &str) -> (u64, u64) {
    let line = stderr
        .lines()
        .find(|l| l.contains("pcimg: network:"))
        .unwrap_or_else(|| panic!("no network line in:\n{stderr}"));
    let n: Vec<u64> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter_map(|w| w.parse().ok())
        .collect();
    (n[0], n[1])
}

/// The cube of the root's first octant, 1 % inside (from the COPC info VLR:
/// centre at byte 429, half size at 453).
fn octant_box() -> ([f64; 3], [f64; 3]) {
    let b = std::fs::read(fixture("autzen_trim.copc.laz")).unwrap();
    let f = |at: usize| f64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let (c, h) = ([f(429), f(437), f(445)], f(453));
    let lo: [f64; 3] = std::array::from_fn(|a| c[a] - h + 0.01 * h);
    let hi: [f64; 3] = std::array::from_fn(|a| c[a] - 0.01 * h);
    (lo, hi)
}

const BOUNDS: &str = "636001,848935,636500,849200";
const LO: [f64; 3] = [636001.0, 848935.0, f64::NEG_INFINITY];
const HI: [f64; 3] = [636500.0, 849200.0, f64::INFINITY];

#[test]
fn a_region_of_a_local_copc_holds_exactly_the_laz_points_inside_it() {
    let t = tempfile::tempdir().unwrap();
    let copc = fixture("autzen_trim.copc.laz");
    let copc = copc.to_str().unwrap();
    // `info` describes it without converting: the octree's levels.
    let o = pcimg().args(["info", "--json", copc]).output().unwrap();
    let v: serde_json::Value = serde_json::from_str(&ok(&o, "info")).unwrap();
    let levels = v["levels"].as_array().unwrap();
    let per_level: Vec<(u64, u64)> = levels
        .iter()
        .map(|l| (l["nodes"].as_u64().unwrap(), l["points"].as_u64().unwrap()))
        .collect();
    assert_eq!(per_level, [(1, 9_260), (8, 100_740)]);
    assert_eq!(v["point_format"].as_u64(), Some(7));
    let whole = t.path().join("whole.pcimg");
    ok(&convert(copc, &whole, &["-q"]), "convert");
    assert_eq!(points(&whole), 110_000);
    let part = t.path().join("part.pcimg");
    let o = convert(copc, &part, &["--bounds", BOUNDS]);
    let said = String::from_utf8_lossy(&o.stderr).into_owned() + &ok(&o, "convert --bounds");
    let want = laz_points_inside(LO, HI);
    assert!(want > 1000 && want < 110_000, "{want}");
    assert_eq!(points(&part), want);
    assert!(
        said.contains("octree nodes that reach the region"),
        "{said}"
    );
    // A box in 3D.
    let clipped = t.path().join("clip.pcimg");
    let o = convert(
        copc,
        &clipped,
        &["-q", "--clip", "636001,848935,400,636500,849200,430"],
    );
    ok(&o, "convert --clip");
    let want3 = laz_points_inside([636001.0, 848935.0, 400.0], [636500.0, 849200.0, 430.0]);
    assert!(want3 > 0 && want3 < want);
    assert_eq!(points(&clipped), want3);
    // A region no point reaches: said, not an empty dataset.
    let none = t.path().join("none.pcimg");
    let e = err(
        &convert(copc, &none, &["-q", "--bounds", "0,0,1,1"]),
        "an empty region",
    );
    assert!(e.contains("autzen_trim.copc.laz"), "{e}");
    assert!(!none.exists());
    // Other formats refuse a region, naming the file.
    let laz = fixture("autzen_trim.laz");
    let e = err(
        &convert(laz.to_str().unwrap(), &none, &["--bounds", BOUNDS]),
        "a region of a LAZ",
    );
    assert!(
        e.contains("autzen_trim.laz") && e.contains("only from COPC"),
        "{e}"
    );
    let e = err(
        &convert(copc, &none, &["--bounds", "5,0,1,1"]),
        "a reversed box",
    );
    assert!(e.contains("above its maximum"), "{e}");
}

/// The fixture with `patch` written at byte `at`, as `name` in `dir`.
fn patched(dir: &Path, name: &str, at: usize, patch: &[u8]) -> PathBuf {
    let mut b = std::fs::read(fixture("autzen_trim.copc.laz")).unwrap();
    b[at..at + patch.len()].copy_from_slice(patch);
    let p = dir.join(name);
    std::fs::write(&p, b).unwrap();
    p
}

#[test]
fn bad_copc_files_are_named_with_the_byte_offset() {
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("out.pcimg");
    let run = |p: &Path| {
        let o = convert(p.to_str().unwrap(), &out, &["--bounds", BOUNDS]);
        err(&o, &p.display().to_string())
    };
    // A LAS 1.4 file whose first VLR is not COPC's.
    let e = run(&patched(t.path(), "claims.copc.laz", 377, b"notcopc\0"));
    assert!(
        e.contains("claims.copc.laz") && e.contains("only from COPC"),
        "{e}"
    );
    // The root hierarchy page said to be 8 bytes shorter (not whole entries).
    let b = std::fs::read(fixture("autzen_trim.copc.laz")).unwrap();
    let size = u64::from_le_bytes(b[477..485].try_into().unwrap());
    let at = u64::from_le_bytes(b[469..477].try_into().unwrap());
    let e = run(&patched(
        t.path(),
        "short.copc.laz",
        477,
        &(size - 8).to_le_bytes(),
    ));
    assert!(
        e.contains("short.copc.laz") && e.contains(&format!("byte offset {at}")),
        "{e}"
    );
    // The root node's point count one more than its chunk holds.
    let count_at = at as usize + 28;
    let n = u32::from_le_bytes(b[count_at..count_at + 4].try_into().unwrap());
    let e = run(&patched(
        t.path(),
        "count.copc.laz",
        count_at,
        &(n + 1).to_le_bytes(),
    ));
    assert!(
        e.contains("count.copc.laz") && e.contains("the hierarchy says"),
        "{e}"
    );
    assert!(!out.exists());
}

/// Mutated COPC files read by region: errors or points, never a panic.
#[test]
fn mutated_copc_files_never_panic() {
    let t = tempfile::tempdir().unwrap();
    let good = std::fs::read(fixture("autzen_trim.copc.laz")).unwrap();
    let mut rng = pcimg::synth::Rng::new(42);
    let hier = u64::from_le_bytes(good[469..477].try_into().unwrap()) as usize;
    for k in 0..60 {
        let mut b = good.clone();
        // Into the header and VLRs, the hierarchy, or anywhere.
        let span = match k % 3 {
            0 => 0..1400,
            1 => hier..good.len(),
            _ => 0..good.len(),
        };
        for _ in 0..1 + rng.next_u64() % 4 {
            let i = span.start + (rng.next_u64() as usize) % (span.end - span.start);
            b[i] = rng.next_u64() as u8;
        }
        if k % 10 == 9 {
            b.truncate((rng.next_u64() as usize) % good.len());
        }
        let p = t.path().join(format!("m{k}.copc.laz"));
        std::fs::write(&p, &b).unwrap();
        let out = t.path().join(format!("m{k}.pcimg"));
        let o = convert(p.to_str().unwrap(), &out, &["-q", "--bounds", BOUNDS]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!e.contains("panicked"), "mutation {k}: {e}");
        assert!(o.status.code().is_some_and(|c| c <= 1), "mutation {k}: {e}");
    }
}

#[test]
fn a_copc_over_http_reads_the_same_points() {
    let t = tempfile::tempdir().unwrap();
    std::fs::copy(
        fixture("autzen_trim.copc.laz"),
        t.path().join("autzen_trim.copc.laz"),
    )
    .unwrap();
    let Some(server) = common::http::HttpServer::start(t.path()) else {
        return;
    };
    let url = server.url("autzen_trim.copc.laz");
    let out = t.path().join("part.pcimg");
    let o = convert(&url, &out, &["-q", "--bounds", BOUNDS, "--net-stats"]);
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    ok(&o, "convert over HTTP");
    assert_eq!(points(&out), laz_points_inside(LO, HI));
    // Python's server ignores Range: the file comes whole, once (the first
    // ranged request answered whole, then one plain GET).
    let (requests, _) = network(&e);
    assert!(requests <= 2, "{e}");
    // A missing file names the URL.
    let o = convert(
        &server.url("none.copc.laz"),
        &t.path().join("n.pcimg"),
        &["-q"],
    );
    let e = err(&o, "a missing URL");
    assert!(e.contains("none.copc.laz"), "{e}");
    // A URL input needs -o.
    let o = pcimg().args(["convert", &url]).output().unwrap();
    assert!(err(&o, "no -o").contains("-o"));
}

#[test]
fn a_copc_in_object_storage_fetches_only_the_nodes_of_the_region() {
    let Some(weed) = common::servers::Weed::start() else {
        return;
    };
    let bytes = std::fs::read(fixture("autzen_trim.copc.laz")).unwrap();
    let len = bytes.len() as u64;
    weed.put("lidar/autzen_trim.copc.laz", bytes).unwrap();
    let url = format!(
        "s3://{}/lidar/autzen_trim.copc.laz",
        common::servers::WEED_BUCKET
    );
    let t = tempfile::tempdir().unwrap();
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec!["convert", url.as_str(), "-o", out.to_str().unwrap(), "-q"];
        args.extend_from_slice(extra);
        args.push("--net-stats");
        let o = weed.pcimg(&weed.endpoint(), &args).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr).into_owned();
        ok(&o, "convert from S3");
        network(&e)
    };
    // Opening it (`info`) is two requests: the header, the root page.
    let o = weed
        .pcimg(&weed.endpoint(), &["info", "--json", "--net-stats", &url])
        .output()
        .unwrap();
    let said = ok(&o, "info of a COPC in S3");
    let (opening, _) = network(&String::from_utf8_lossy(&o.stderr));
    assert!(opening <= 2, "{opening} requests to open");
    let v: serde_json::Value = serde_json::from_str(&said).unwrap();
    assert_eq!(
        (v["points"].as_u64(), v["format"].as_str()),
        (Some(110_000), Some("copc"))
    );
    let whole = t.path().join("whole.pcimg");
    let (all_requests, all_bytes) = run(&whole, &[]);
    assert_eq!(points(&whole), 110_000);
    // Header and root page, then the nine chunks merged into one range.
    assert!(all_requests <= 3, "{all_requests} requests");
    assert!(all_bytes >= len - 2048, "{all_bytes} of {len}");
    // A frame of one octant (`render --clip`) fetches the root and that
    // octant's node, not the file (after the two requests that open it).
    let (lo, hi) = octant_box();
    let clip = format!(
        "{},{},{},{},{},{}",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    );
    let png = t.path().join("octant.png");
    let o = weed
        .pcimg(
            &weed.endpoint(),
            &[
                "render",
                &url,
                "--clip",
                &clip,
                "--net-stats",
                "-o",
                png.to_str().unwrap(),
            ],
        )
        .output()
        .unwrap();
    ok(&o, "render --clip from S3");
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    let (frame_requests, frame_bytes) = network(&e);
    eprintln!("S3 frame of one octant: {frame_requests} requests, {frame_bytes} bytes");
    assert!(e.contains("from 2 tiles"), "{e}");
    assert!(frame_requests <= 4, "{e}");
    assert!(frame_bytes < len * 6 / 10, "{e}");
    let part = t.path().join("part.pcimg");
    let (requests, got) = run(&part, &["--bounds", BOUNDS]);
    assert_eq!(points(&part), laz_points_inside(LO, HI));
    eprintln!(
        "S3: whole file {all_requests} requests, {all_bytes} bytes; region {requests} \
         requests, {got} bytes (file {len} bytes)"
    );
    assert!(requests <= 4, "{requests} requests");
    assert!(got < len * 6 / 10, "{got} bytes of {len}");
}

/// The pixels of the PNG at `p` that are not the background (black).
fn footprint(p: &Path) -> Vec<bool> {
    let img = image::open(p).unwrap().to_rgba8();
    img.pixels().map(|px| px.0[..3] != [0, 0, 0]).collect()
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    inter as f64 / union.max(1) as f64
}

/// `render` draws a COPC file from its octree, with no conversion: the frame
/// covers the pixels the converted points cover, in colour and by class; a
/// small budget draws the root node alone.
#[test]
fn a_copc_renders_as_its_converted_points_do() {
    let t = tempfile::tempdir().unwrap();
    let copc = fixture("autzen_trim.copc.laz");
    let converted = t.path().join("c.pcimg");
    common::cli::convert(&copc, &converted, &[]);
    let render = |input: &Path, png: &str, extra: &[&str]| {
        let out = t.path().join(png);
        let o = pcimg()
            .arg("render")
            .arg(input)
            .args(["--width", "480", "--height", "320", "-o"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&o.stderr).into_owned();
        ok(&o, "render");
        (out, said)
    };
    for color in ["rgb", "classification", "elevation"] {
        let (a, said) = render(&copc, &format!("copc-{color}.png"), &["--color", color]);
        assert!(said.contains("110,000 points from 9 tiles"), "{said}");
        let (b, _) = render(
            &converted,
            &format!("conv-{color}.png"),
            &["--color", color],
        );
        let (fa, fb) = (footprint(&a), footprint(&b));
        let v = iou(&fa, &fb);
        eprintln!("{color}: footprint IoU {v:.4}");
        assert!(v >= 0.95, "{color}: footprint IoU {v:.3}");
        assert!(fa.iter().filter(|&&p| p).count() > 10_000);
    }
    let (_, said) = render(&copc, "root.png", &["--budget", "10000"]);
    assert!(said.contains("9,260 points from 1 tiles"), "{said}");
    // Picking the point at the frame's centre gives every field of it.
    let o = pcimg()
        .arg("render")
        .arg(&copc)
        .args([
            "--width", "480", "--height", "320", "--pick", "240,160", "-o",
        ])
        .arg(t.path().join("pick.png"))
        .output()
        .unwrap();
    let v: serde_json::Value =
        serde_json::from_str(ok(&o, "render --pick").lines().next().unwrap()).unwrap();
    assert!(
        v["part"]
            .as_str()
            .unwrap()
            .ends_with("autzen_trim.copc.laz"),
        "{v}"
    );
    for f in ["classification", "gps_time", "intensity", "red"] {
        assert!(v["attributes"][f].is_number(), "{f} in {v}");
    }
}

/// The camera a 480×320 frame of `input` is fitted to (`--print-camera`), as
/// `--camera` takes it: one camera for frames of two inputs.
fn camera_of(input: &Path, scratch: &Path) -> String {
    let o = pcimg()
        .arg("render")
        .arg(input)
        .args(["--width", "480", "--height", "320", "--print-camera", "-o"])
        .arg(scratch.join("probe.png"))
        .output()
        .unwrap();
    let said = ok(&o, "render --print-camera") + &String::from_utf8_lossy(&o.stderr);
    said.lines()
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no camera in {said}"))
        .to_string()
}

/// PDAL's EPT test dataset `lone-star-laszip` (fixtures/ept/, BSD).
fn ept() -> PathBuf {
    fixture("ept/lone-star-laszip/ept.json")
}

/// Every point of every node file of the EPT, read by the `las` crate: each
/// point's position (on the 0.00025 m lattice) and intensity.
fn ept_points_by_las(lo: [f64; 3], hi: [f64; 3]) -> Vec<(i64, i64, i64, u16)> {
    let dir = fixture("ept/lone-star-laszip/ept-data");
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let mut r = las::Reader::from_path(e.unwrap().path()).unwrap();
        for p in r.read_all().unwrap().points() {
            let p = p.unwrap();
            let c = [p.x, p.y, p.z];
            if (0..3).all(|a| c[a] >= lo[a] && c[a] <= hi[a]) {
                let q = |x: f64| (x / 0.00025).round() as i64;
                v.push((q(p.x), q(p.y), q(p.z), p.intensity));
            }
        }
    }
    v.sort_unstable();
    v
}

/// An EPT dataset converts (whole, or by region reading only the nodes that
/// reach it) to exactly the points its node files hold; `info` reads the root
/// hierarchy file alone; a node file whose count disagrees with the hierarchy
/// and a missing node file are errors naming the file.
#[test]
fn an_ept_dataset_converts_whole_and_by_region_to_its_nodes_points() {
    let t = tempfile::tempdir().unwrap();
    let input = ept();
    let input = input.to_str().unwrap();
    let all = ept_points_by_las([f64::NEG_INFINITY; 3], [f64::INFINITY; 3]);
    assert_eq!(all.len(), 518_862);
    let whole = t.path().join("whole.pcimg");
    ok(&convert(input, &whole, &["-q"]), "convert EPT");
    assert_eq!(points(&whole), 518_862);
    // Our points, back out through export (LAS), equal the node files'.
    let las_out = t.path().join("back.las");
    let o = pcimg()
        .args(["export"])
        .arg(&whole)
        .arg("-o")
        .arg(&las_out)
        .output()
        .unwrap();
    ok(&o, "export");
    let mut back: Vec<(i64, i64, i64, u16)> = las::Reader::from_path(&las_out)
        .unwrap()
        .read_all()
        .unwrap()
        .points()
        .map(|p| {
            let p = p.unwrap();
            let q = |x: f64| (x / 0.00025).round() as i64;
            (q(p.x), q(p.y), q(p.z), p.intensity)
        })
        .collect();
    back.sort_unstable();
    assert!(
        back == all,
        "the exported points differ from the node files'"
    );
    // A region: the west half.
    let (lo, hi) = (
        [515363.0, 4918339.0, f64::NEG_INFINITY],
        [515385.0, 4918383.0, f64::INFINITY],
    );
    let part = t.path().join("part.pcimg");
    let o = convert(input, &part, &["--bounds", "515363,4918339,515385,4918383"]);
    let said = String::from_utf8_lossy(&o.stderr).into_owned() + &ok(&o, "convert --bounds");
    let want = ept_points_by_las(lo, hi).len() as u64;
    assert!(want > 1000 && want < 518_862);
    assert_eq!(points(&part), want);
    assert!(
        said.contains("octree nodes that reach the region"),
        "{said}"
    );
    // info: the root hierarchy file alone, unless --tiles.
    let o = pcimg().args(["info", "--json", input]).output().unwrap();
    let v: serde_json::Value = serde_json::from_str(&ok(&o, "info")).unwrap();
    assert_eq!(v["hierarchy_files_read"].as_u64(), Some(1));
    assert_eq!(v["points"].as_u64(), Some(518_862));
    let o = pcimg()
        .args(["info", "--json", "--tiles", input])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_str(&ok(&o, "info --tiles")).unwrap();
    let sum: u64 = v["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["points"].as_u64().unwrap())
        .sum();
    assert_eq!(sum, 518_862);
    // PDAL's dataset whose hierarchy says 1000 where the file holds 1065.
    let bad = fixture("ept/bad-pointcount/laszip/ept.json");
    let e = err(
        &convert(bad.to_str().unwrap(), &t.path().join("b.pcimg"), &["-q"]),
        "bad count",
    );
    assert!(
        e.contains("0-0-0-0.laz") && e.contains("the hierarchy says 1000"),
        "{e}"
    );
    // A node file missing: named.
    let copy = t.path().join("ept");
    for sub in ["", "ept-hierarchy", "ept-data"] {
        std::fs::create_dir_all(copy.join(sub)).unwrap();
        let from = fixture("ept/lone-star-laszip").join(sub);
        for f in std::fs::read_dir(from).unwrap() {
            let f = f.unwrap();
            if f.file_type().unwrap().is_file() {
                std::fs::copy(f.path(), copy.join(sub).join(f.file_name())).unwrap();
            }
        }
    }
    std::fs::remove_file(copy.join("ept-data/2-2-2-2.laz")).unwrap();
    let e = err(
        &convert(
            copy.join("ept.json").to_str().unwrap(),
            &t.path().join("m.pcimg"),
            &["-q"],
        ),
        "a missing node",
    );
    assert!(e.contains("2-2-2-2.laz"), "{e}");
}

/// `render` draws an EPT dataset from its octree as its converted points draw.
#[test]
fn an_ept_dataset_renders_as_its_converted_points_do() {
    let t = tempfile::tempdir().unwrap();
    let converted = t.path().join("c.pcimg");
    common::cli::convert(&ept(), &converted, &[]);
    // One camera for both (ept.json's bounds are rounded outward: a camera
    // fitted to each would differ).
    let camera = camera_of(&converted, t.path());
    let render = |input: &Path, png: &str| {
        let out = t.path().join(png);
        let o = pcimg()
            .arg("render")
            .arg(input)
            .args([
                "--width", "480", "--height", "320", "--lod", "0", "--camera", &camera, "-o",
            ])
            .arg(&out)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&o.stderr).into_owned();
        ok(&o, "render");
        (out, said)
    };
    let (a, said) = render(&ept(), "ept.png");
    assert!(said.contains("518,862 points from 13 tiles"), "{said}");
    let (b, _) = render(&converted, "conv.png");
    let v = iou(&footprint(&a), &footprint(&b));
    eprintln!("EPT footprint IoU {v:.4}");
    assert!(v >= 0.95, "footprint IoU {v:.3}");
}

/// An EPT dataset served by `python3 -m http.server` renders and converts by
/// region over HTTP.
#[test]
fn an_ept_dataset_over_http() {
    let Some(server) = common::http::HttpServer::start(&fixture("ept")) else {
        return;
    };
    let t = tempfile::tempdir().unwrap();
    let url = server.url("lone-star-laszip/ept.json");
    let part = t.path().join("part.pcimg");
    let o = convert(
        &url,
        &part,
        &["-q", "--bounds", "515363,4918339,515385,4918383"],
    );
    ok(&o, "convert an EPT over HTTP");
    let want = ept_points_by_las(
        [515363.0, 4918339.0, f64::NEG_INFINITY],
        [515385.0, 4918383.0, f64::INFINITY],
    );
    assert_eq!(points(&part), want.len() as u64);
    let png = t.path().join("e.png");
    let o = pcimg()
        .args(["render", &url, "-o"])
        .arg(&png)
        .output()
        .unwrap();
    ok(&o, "render an EPT over HTTP");
}

/// The four quadrants of autzen_trim.laz, each made a COPC file by
/// `copc_converter` (fixtures/survey/), copied into `dir`.
fn quadrants(dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    ["q00", "q01", "q10", "q11"]
        .iter()
        .map(|q| {
            let name = format!("autzen-{q}.copc.laz");
            let to = dir.join(&name);
            std::fs::copy(fixture(&format!("survey/{name}")), &to).unwrap();
            to
        })
        .collect()
}

/// `pcimg index LIST -o OUT`.
fn index_list(list: &Path, out: &Path) -> std::process::Output {
    pcimg()
        .arg("index")
        .arg(list)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap()
}

/// What a directory holds besides `keep`'s names (temporary or half-made
/// things a failed index would leave).
fn others(dir: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.iter().any(|k| n.ends_with(k)))
        .collect()
}

/// `pcimg index` over a directory of COPC tiles writes a survey: one dataset
/// of them all whose first frame draws the overview node built from their
/// root nodes, whose full frame covers what the whole COPC covers, and which
/// opens no file until a view reaches it.
#[test]
fn copc_tiles_indexed_as_a_survey_are_one_dataset() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("tiles");
    let files = quadrants(&dir);
    let o = pcimg().arg("index").arg(&dir).output().unwrap();
    let said = ok(&o, "index of COPC tiles");
    assert!(
        said.contains("surveyed 4 COPC file(s), 110,000 points"),
        "{said}"
    );
    assert!(dir.join("pcimg-survey.json").is_file());
    assert!(
        others(&dir, &[".copc.laz", "pcimg-survey.json"])
            .iter()
            .all(|n| n.starts_with("survey-overview-")),
        "{:?}",
        others(&dir, &[])
    );
    // Indexed again, twice: the new overview replaces the old, which stays
    // (for readers that opened it) until the rebuild after.
    for _ in 0..2 {
        let o = pcimg().arg("index").arg(&dir).output().unwrap();
        ok(&o, "index again");
        let folders: Vec<String> = others(&dir, &[".copc.laz", "pcimg-survey.json"]);
        assert_eq!(folders.len(), 2, "{folders:?}");
    }
    let o = pcimg().args(["info", "--json"]).arg(&dir).output().unwrap();
    let v: serde_json::Value = serde_json::from_str(&ok(&o, "info of a survey")).unwrap();
    assert_eq!(
        (
            v["format"].as_str(),
            v["files"].as_u64(),
            v["points"].as_u64()
        ),
        (Some("copc-survey"), Some(4), Some(110_000)),
        "{v}"
    );
    // One camera for the survey and for the COPC of all the points.
    let whole = fixture("autzen_trim.copc.laz");
    let camera = camera_of(&whole, t.path());
    let render = |input: &Path, png: &str, extra: &[&str]| {
        let out = t.path().join(png);
        let o = pcimg()
            .arg("render")
            .arg(input)
            .args(["--width", "480", "--height", "320", "--camera", &camera])
            .args(extra)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&o.stderr).into_owned();
        ok(&o, "render");
        (out, said)
    };
    let (a, said) = render(&dir, "survey.png", &[]);
    assert!(said.contains("110,000 points from 4 tiles"), "{said}");
    let (b, _) = render(&whole, "whole.png", &[]);
    let v = iou(&footprint(&a), &footprint(&b));
    eprintln!("survey against the whole COPC: footprint IoU {v:.4}");
    assert!(v >= 0.95, "footprint IoU {v:.3}");
    // A small budget draws the overview node alone: a quarter of the roots.
    let (c, said) = render(&dir, "top.png", &["--budget", "40000"]);
    assert!(said.contains("27,502 points from 1 tiles"), "{said}");
    let v = iou(&footprint(&c), &footprint(&b));
    eprintln!("overview node against the whole COPC: footprint IoU {v:.4}");
    assert!(v >= 0.5, "footprint IoU {v:.3}");
    // A pick names the COPC file the point came from.
    let o = pcimg()
        .arg("render")
        .arg(&dir)
        .args(["--width", "480", "--height", "320", "--camera", &camera])
        .args(["--pick", "240,160", "-o"])
        .arg(t.path().join("pick.png"))
        .output()
        .unwrap();
    let v: serde_json::Value =
        serde_json::from_str(ok(&o, "render --pick").lines().next().unwrap()).unwrap();
    let from = v["part"].as_str().unwrap_or_default();
    assert!(
        from.contains("autzen-q") && from.ends_with(".copc.laz"),
        "{v}"
    );
    assert!(v["attributes"]["classification"].is_number(), "{v}");
    // `--lod 1` (all but the deepest depth): the overview node, which the
    // files' roots replace.
    let (_, said) = render(&dir, "lod1.png", &["--lod", "1"]);
    assert!(said.contains("27,502 points from 1 tiles"), "{said}");

    // A list of files (paths relative to it) into another directory.
    let list = t.path().join("tiles.txt");
    std::fs::write(
        &list,
        "# the quadrants\ntiles/autzen-q00.copc.laz\n\ntiles/autzen-q01.copc.laz\n\
         tiles/autzen-q10.copc.laz\ntiles/autzen-q11.copc.laz\n",
    )
    .unwrap();
    let out = t.path().join("out");
    ok(&index_list(&list, &out), "index of a list");
    let (_, said) = render(&out.join("pcimg-survey.json"), "list.png", &[]);
    assert!(said.contains("110,000 points from 4 tiles"), "{said}");
    // A list needs -o.
    let o = pcimg().arg("index").arg(&list).output().unwrap();
    assert!(err(&o, "a list with no -o").contains("-o DIR"));

    // A region converts from the files whose recorded bounds reach it alone
    // (autzen-q00 here), to exactly the points inside it.
    let region = t.path().join("region.pcimg");
    let o = convert(dir.to_str().unwrap(), &region, &["--bounds", BOUNDS]);
    let said = ok(&o, "convert a survey by region");
    assert!(
        said.contains("autzen-q00") && !said.contains("autzen-q11"),
        "{said}"
    );
    assert_eq!(points(&region), laz_points_inside(LO, HI));
    let o = convert(
        dir.to_str().unwrap(),
        &t.path().join("none.pcimg"),
        &["--bounds", "0,0,1,1"],
    );
    assert!(err(&o, "a region off the survey").contains("no file of the survey reaches"));
    // `export` reads datasets of parts: for the survey's directory it says to
    // convert it.
    let o = pcimg()
        .arg("export")
        .arg(&dir)
        .arg("-o")
        .arg(t.path().join("x.las"))
        .output()
        .unwrap();
    let e = err(&o, "export of a survey");
    assert!(
        e.contains("4 point-cloud file(s)") && e.contains("pcimg convert"),
        "{e}"
    );
    // A file that changed since the survey is named, with what to do.
    std::fs::copy(&files[3], &files[0]).unwrap();
    let o = pcimg()
        .arg("render")
        .arg(&dir)
        .arg("-o")
        .arg(t.path().join("stale.png"))
        .output()
        .unwrap();
    let e = err(&o, "a changed file");
    assert!(
        e.contains("autzen-q00.copc.laz") && e.contains("pcimg index"),
        "{e}"
    );
}

/// A survey's bad inputs are named, and a failed index leaves nothing in its
/// output directory.
#[test]
fn a_survey_of_bad_inputs_is_refused_and_leaves_nothing() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("tiles");
    quadrants(&dir);
    let out = t.path().join("out");
    let index = |lines: &str| {
        let list = t.path().join("list.txt");
        std::fs::write(&list, lines).unwrap();
        let e = err(&index_list(&list, &out), lines);
        assert!(!out.exists(), "{lines}: left {:?}", others(&out, &[]));
        e
    };
    let e = index("tiles/autzen-q00.copc.laz\ntiles/missing.copc.laz\n");
    assert!(e.contains("missing.copc.laz"), "{e}");
    // A LAS file is not COPC.
    std::fs::copy(fixture("autzen_trim.laz"), dir.join("plain.laz")).unwrap();
    let e = index("tiles/autzen-q00.copc.laz\ntiles/plain.laz\n");
    assert!(e.contains("plain.laz") && e.contains("COPC"), "{e}");
    let e = index("ftp://example.com/a.copc.laz\n");
    assert!(e.contains("list.txt:1"), "{e}");
    let e = index("# nothing\n");
    assert!(e.contains("lists no files"), "{e}");
}

/// A survey served by `python3 -m http.server`: `info` reads the survey
/// file alone, a first frame reads it and the overview node, no COPC file.
#[test]
fn a_survey_over_http_reads_only_what_its_frame_draws() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("tiles");
    quadrants(&dir);
    let o = pcimg().arg("index").arg(&dir).output().unwrap();
    ok(&o, "index");
    let Some(server) = common::http::HttpServer::start(&dir) else {
        return;
    };
    let url = server.url("pcimg-survey.json");
    let o = pcimg()
        .args(["info", "--net-stats", &url])
        .output()
        .unwrap();
    let said = ok(&o, "info of a survey over HTTP");
    assert!(said.contains("4 COPC files, 110,000 points"), "{said}");
    assert_eq!(network(&String::from_utf8_lossy(&o.stderr)).0, 1);
    let frame = |extra: &[&str]| {
        let o = pcimg()
            .args(["render", &url, "--net-stats", "-o"])
            .arg(t.path().join("f.png"))
            .args(extra)
            .output()
            .unwrap();
        ok(&o, "render a survey over HTTP");
        let e = String::from_utf8_lossy(&o.stderr).into_owned();
        (network(&e).0, e)
    };
    let (requests, e) = frame(&["--budget", "40000"]);
    assert!(e.contains("27,502 points from 1 tiles"), "{e}");
    assert!(requests <= 2, "{e}");
    let (_, e) = frame(&[]);
    assert!(e.contains("110,000 points from 4 tiles"), "{e}");
    // A survey that is not there is named.
    let missing = server.url("none/pcimg-survey.json");
    let o = pcimg()
        .args(["render", &missing, "-o"])
        .arg(t.path().join("m.png"))
        .output()
        .unwrap();
    let e = err(&o, "a missing survey");
    assert!(e.contains("none/pcimg-survey.json"), "{e}");
}

/// laspy's COPC test files (fixtures/laspy/, written by another COPC writer
/// than autzen_trim's): `simple_with_page.copc.laz` keeps its octree's
/// hierarchy in two pages. `info` reads the root page alone (`--tiles`
/// both), and every point read through the octree (a region covering all,
/// which reads node by node) equals laspy's `simple.las` it was made from.
#[test]
fn laspys_paged_copc_reads_its_second_page_only_when_asked() {
    let t = tempfile::tempdir().unwrap();
    let paged = fixture("laspy/simple_with_page.copc.laz");
    let info = |extra: &[&str]| -> serde_json::Value {
        let o = pcimg()
            .args(["info", "--json"])
            .args(extra)
            .arg(&paged)
            .output()
            .unwrap();
        serde_json::from_str(&ok(&o, "info")).unwrap()
    };
    let v = info(&[]);
    assert_eq!(
        (v["pages_read"].as_u64(), v["pages_unread"].as_u64()),
        (Some(1), Some(1)),
        "{v}"
    );
    let v = info(&["--tiles"]);
    assert_eq!(
        (v["pages_read"].as_u64(), v["pages_unread"].as_u64()),
        (Some(2), Some(0)),
        "{v}"
    );
    let sum: u64 = v["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["points"].as_u64().unwrap())
        .sum();
    assert_eq!(sum, 1065);
    let key = |p: las::Point| {
        let q = |x: f64| (x * 100.0).round() as i64;
        let c = p.color.map(|c| (c.red, c.green, c.blue));
        (
            q(p.x),
            q(p.y),
            q(p.z),
            p.intensity,
            u8::from(p.classification),
            p.return_number,
            c,
        )
    };
    let read = |p: &Path| -> Vec<_> {
        let mut r = las::Reader::from_path(p).unwrap();
        r.read_all()
            .unwrap()
            .points()
            .map(|p| key(p.unwrap()))
            .collect()
    };
    let mut want = read(&fixture("laspy/simple.las"));
    want.sort_unstable();
    for name in ["simple_with_page.copc.laz", "simple.copc.laz"] {
        let part = t.path().join(format!("{name}.pcimg"));
        let o = convert(
            fixture(&format!("laspy/{name}")).to_str().unwrap(),
            &part,
            &["-q", "--bounds", "0,0,1e9,1e9"],
        );
        ok(&o, "convert by region");
        let las_out = t.path().join(format!("{name}.las"));
        let o = pcimg()
            .arg("export")
            .arg(&part)
            .arg("-o")
            .arg(&las_out)
            .output()
            .unwrap();
        ok(&o, "export");
        let mut got = read(&las_out);
        got.sort_unstable();
        assert_eq!(got.len(), want.len(), "{name}");
        assert!(got == want, "{name}: the points differ from simple.las");
    }
}

/// Every file under `dir`, uploaded to `weed` under `prefix/`.
fn upload_dir(weed: &common::servers::Weed, dir: &Path, prefix: &str) {
    for (name, _) in common::cli::local_files(dir) {
        let bytes = std::fs::read(dir.join(&name)).unwrap();
        weed.put(&format!("{prefix}/{name}"), bytes).unwrap();
    }
}

/// In SeaweedFS: a survey of COPC files in the bucket (indexed from their
/// URLs, uploaded beside them) opens in one request and draws its first frame
/// from the overview node in one more; an EPT dataset reads from there too.
#[test]
fn a_survey_and_an_ept_dataset_in_object_storage() {
    let Some(weed) = common::servers::Weed::start() else {
        return;
    };
    let bucket = common::servers::WEED_BUCKET;
    let t = tempfile::tempdir().unwrap();
    let tiles = t.path().join("tiles");
    let files = quadrants(&tiles);
    upload_dir(&weed, &tiles, "lidar/tiles");
    let list = t.path().join("tiles.txt");
    let urls: Vec<String> = files
        .iter()
        .map(|f| {
            format!(
                "s3://{bucket}/lidar/tiles/{}",
                f.file_name().unwrap().to_string_lossy()
            )
        })
        .collect();
    std::fs::write(&list, urls.join("\n")).unwrap();
    let survey = t.path().join("survey");
    let o = weed
        .pcimg(
            &weed.endpoint(),
            &[
                "index",
                list.to_str().unwrap(),
                "-o",
                survey.to_str().unwrap(),
            ],
        )
        .output()
        .unwrap();
    ok(&o, "index of COPC files in S3");
    upload_dir(&weed, &survey, "lidar/survey");
    let url = format!("s3://{bucket}/lidar/survey/pcimg-survey.json");
    let run = |args: &[&str]| {
        let mut a = args.to_vec();
        a.push("--net-stats");
        let o = weed.pcimg(&weed.endpoint(), &a).output().unwrap();
        let said = ok(&o, &args.join(" "));
        let e = String::from_utf8_lossy(&o.stderr).into_owned();
        (said, network(&e).0, e)
    };
    let (said, requests, _) = run(&["info", &url]);
    assert!(said.contains("4 COPC files, 110,000 points"), "{said}");
    assert_eq!(requests, 1);
    let png = t.path().join("f.png");
    let png = png.to_str().unwrap();
    let (_, requests, e) = run(&["render", &url, "-o", png, "--budget", "40000"]);
    assert!(e.contains("27,502 points from 1 tiles"), "{e}");
    assert!(requests <= 2, "{e}");
    // The whole survey: each file opened (header, root page) and its node read.
    let (_, requests, e) = run(&["render", &url, "-o", png]);
    assert!(e.contains("110,000 points from 4 tiles"), "{e}");
    assert!(requests <= 1 + 4 * 3, "{e}");

    // An EPT dataset in the bucket: its JSON files read whole.
    upload_dir(&weed, &fixture("ept/lone-star-laszip"), "lidar/ept");
    let ept = format!("s3://{bucket}/lidar/ept/ept.json");
    let (said, requests, _) = run(&["info", &ept]);
    assert!(said.contains("518,862"), "{said}");
    // ept.json, the root hierarchy file, the root node's LAZ header (its
    // fields).
    assert!(requests <= 3, "{requests} requests");
    let (_, _, e) = run(&["render", &ept, "-o", png, "--lod", "0"]);
    assert!(e.contains("518,862 points from 13 tiles"), "{e}");
}
