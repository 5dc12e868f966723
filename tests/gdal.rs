//! GDAL as an independent reader of what pcimg writes, and pcimg as a reader of what
//! GDAL rewrites. Needs gdal-bin (installed by .ci/run; a failure in CI if missing).

mod common;

use pcimg::store::tiff::zorder::z_pixel;
use pcimg::store::{Compression, Part, WriteOptions, write_part};
use std::path::Path;
use std::process::Command;

fn gdal() -> bool {
    common::tool_available("gdalinfo", "--version")
}

fn run(cmd: &str, args: &[&str]) -> String {
    let out = Command::new(cmd).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{cmd} {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `gdal_translate -q OPTIONS SRC DST`.
fn translate(src: &Path, dst: &Path, options: &[&str]) {
    let mut args = vec!["-q"];
    args.extend_from_slice(options);
    args.extend([src.to_str().unwrap(), dst.to_str().unwrap()]);
    run("gdal_translate", &args);
}

fn write(dir: &Path, name: &str, n: usize, c: Compression) -> std::path::PathBuf {
    let path = dir.join(name);
    let opts = WriteOptions {
        compression: c,
        source: Some("cloud.las".into()),
        crs: Some("EPSG:32633".into()),
        ..Default::default()
    };
    write_part(&path, &common::random_cloud(n, 42, 0), &opts).unwrap();
    path
}

#[test]
fn gdalinfo_sees_bands_overviews_and_metadata() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for c in [Compression::None, Compression::Deflate, Compression::Zstd] {
        let path = write(dir.path(), &format!("{}.tif", c.name()), 300_000, c);
        let info: serde_json::Value =
            serde_json::from_str(&run("gdalinfo", &["-json", path.to_str().unwrap()])).unwrap();
        assert_eq!(info["size"], serde_json::json!([1024, 1024]));
        let bands = info["bands"].as_array().unwrap();
        let names: Vec<&str> = bands
            .iter()
            .map(|b| b["description"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["x", "y", "z", "intensity", "gps_time"]);
        for b in bands {
            assert_eq!(b["type"], "Float32");
            assert_eq!(b["block"], serde_json::json!([256, 256]));
            let ovr: Vec<&serde_json::Value> = b["overviews"]
                .as_array()
                .unwrap()
                .iter()
                .map(|o| &o["size"])
                .collect();
            assert_eq!(
                ovr,
                [
                    &serde_json::json!([512, 512]),
                    &serde_json::json!([256, 256])
                ]
            );
            assert!(
                b["noDataValue"]
                    .as_str()
                    .is_some_and(|s| s.eq_ignore_ascii_case("nan"))
            );
        }
        let part = Part::open(&path).unwrap();
        let x_offset = bands[0]["offset"].as_f64().unwrap();
        assert!((x_offset - part.meta.origin[0]).abs() < 1e-6);
        let md = &info["metadata"][""];
        assert_eq!(md["POINT_COUNT"], "300000");
        // Zstd and Deflate parts are version 2 (row-ordered tiles).
        let version = if c == Compression::None { "1" } else { "2" };
        assert_eq!(md["PCIMG_FORMAT"], version);
        assert_eq!(md["LEVEL_POINTS"], "300000 75000 18750");
        assert_eq!(md["SOURCE"], "cloud.las");
        assert_eq!(md["CRS"], "EPSG:32633");
        assert!(md["BOUNDS_MIN"].as_str().unwrap().starts_with("637179.2"));
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"]["INTERLEAVE"], "BAND",
            "bands are separate planes"
        );
        if c != Compression::None {
            let comp = info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"]
                .as_str()
                .unwrap();
            assert_eq!(
                comp,
                if c == Compression::Deflate {
                    "DEFLATE"
                } else {
                    "ZSTD"
                }
            );
        }
    }
}

/// The pixel of the point of rank `r` (in reading order) at a level of `part`:
/// along the tile's Z-order curve (format version 1), or row-major in its tile
/// (version 2's row-ordered tiles); tiles along the image's Z-order curve.
fn pixel_of(part: &Part, r: u64) -> (u32, u32) {
    if !part
        .meta
        .items
        .contains_key(pcimg::store::spec::key::TILE_ORDER)
    {
        return z_pixel(r);
    }
    let (tc, tr) = z_pixel(r >> 16);
    let i = (r & 0xffff) as u32;
    (tc * 256 + i % 256, tr * 256 + i / 256)
}

/// A value GDAL reads from band `b` (stored, before scale and offset) as
/// pcimg's reader gives it: relative to the band's offset, whole-number bands
/// (version 2: stored plus 2^23, or on a lattice) through GDAL's scale and
/// offset.
fn as_ours(part: &Part, b: usize, v: f32) -> f32 {
    match part.bands[b].lattice {
        Some((step, zero)) => ((zero + step * v as f64) - part.bands[b].offset) as f32,
        None => v,
    }
}

/// `gdallocationinfo` returns our value at pixel of rank `r` of `level`.
fn check_pixels(path: &Path, level: usize, ranks: &[usize]) {
    let part = Part::open(path).unwrap();
    let p = part.read_level(level, &[0, 1, 2, 3]).unwrap();
    for &r in ranks {
        let (px, py) = pixel_of(&part, r as u64);
        // gdallocationinfo takes base-level pixel coordinates even with -overview.
        let (px, py) = (px << level, py << level);
        for band in 1..=4usize {
            let mut args = vec!["-valonly".to_string(), "-b".into(), band.to_string()];
            if level > 0 {
                args.extend(["-overview".into(), level.to_string()]);
            }
            args.extend([
                path.to_str().unwrap().into(),
                px.to_string(),
                py.to_string(),
            ]);
            let out = run(
                "gdallocationinfo",
                &args.iter().map(String::as_str).collect::<Vec<_>>(),
            );
            let v: f32 = out
                .trim()
                .parse()
                .unwrap_or_else(|_| panic!("value '{out}'"));
            let v = as_ours(&part, band - 1, v) as f64;
            let ours = p.columns[band - 1][r] as f64;
            assert!(
                (v - ours).abs() <= ours.abs() * 1e-6 + 1e-6,
                "level {level} rank {r} band {band}: gdal {v} pcimg {ours}"
            );
        }
    }
}

#[test]
fn gdallocationinfo_reads_our_values() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "loc.tif", 300_000, Compression::None);
    check_pixels(&path, 0, &[0, 1, 77, 65_535, 65_536, 299_999]);
    check_pixels(&path, 1, &[0, 3, 74_999]);
    let path = write(dir.path(), "locz.tif", 100_000, Compression::Deflate);
    check_pixels(&path, 0, &[5, 99_999]);
    check_pixels(&path, 1, &[24_999]);
    // Beyond the last point the pixel is nodata.
    let (px, py) = z_pixel(300_000);
    let out = run(
        "gdallocationinfo",
        &[
            "-valonly",
            "-b",
            "1",
            dir.path().join("loc.tif").to_str().unwrap(),
            &px.to_string(),
            &py.to_string(),
        ],
    );
    assert!(out.trim().eq_ignore_ascii_case("nan"), "{out}");
}

/// Every pixel of every level, compressed or not, as GDAL decodes it
/// (`gdal_translate` of the level to raw ENVI floats) is pcimg's value at that
/// pixel's Z-order rank, and NaN past the last point.
#[test]
fn gdal_decodes_every_pixel_of_every_level() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let n = 300_000;
    for c in [Compression::Zstd, Compression::Deflate, Compression::None] {
        let path = write(dir.path(), &format!("all-{}.tif", c.name()), n, c);
        let part = Part::open(&path).unwrap();
        let g = pcimg::store::tiff::zorder::Geometry::for_points(n as u64);
        assert!(g.levels() >= 3, "the test wants overviews");
        for level in 0..g.levels() {
            let raw = dir.path().join(format!("l{level}-{}.bin", c.name()));
            let mut opts = vec!["-of", "ENVI", "-ot", "Float32"];
            let ovr = (level as i64 - 1).to_string();
            if level > 0 {
                opts.extend(["-ovr", ovr.as_str()]);
            }
            translate(&path, &raw, &opts);
            let bytes = std::fs::read(&raw).unwrap();
            let side = g.size(level) as usize;
            let nb = bytes.len() / (4 * side * side);
            assert_eq!(bytes.len(), 4 * nb * side * side, "level {level}");
            assert_eq!(nb, 5, "x y z and the cloud's two attributes");
            let ours = part
                .read_level(level, &(0..nb).collect::<Vec<_>>())
                .unwrap();
            let value = |band: usize, px: u32, py: u32| {
                let at = 4 * (band * side * side + py as usize * side + px as usize);
                as_ours(
                    &part,
                    band,
                    f32::from_ne_bytes(bytes[at..at + 4].try_into().unwrap()),
                )
            };
            let points = g.level_points(level) as usize;
            assert_eq!(ours.len(), points);
            let mut filled = vec![false; side * side];
            for r in 0..points {
                let (px, py) = pixel_of(&part, r as u64);
                filled[py as usize * side + px as usize] = true;
                for band in 0..nb {
                    let v = value(band, px, py);
                    assert_eq!(
                        v.to_bits(),
                        ours.columns[band][r].to_bits(),
                        "{c:?} level {level} rank {r} band {band}"
                    );
                }
            }
            for (i, f) in filled.iter().enumerate() {
                if !f {
                    let (px, py) = ((i % side) as u32, (i / side) as u32);
                    assert!(
                        value(0, px, py).is_nan(),
                        "{c:?} level {level} empty pixel {i}"
                    );
                }
            }
        }
    }
}

/// LERC parts (each band's tile its own blob, as GDAL writes `-co
/// COMPRESS=LERC*` with `INTERLEAVE=BAND`): GDAL decodes every level to our
/// reader's values, bit for bit, and those are the uncompressed part's:
/// coordinates within the part's CODEC_MAX_ERROR (plus f32 rounding),
/// attributes (whole numbers and floats) exactly.
#[test]
fn gdal_decodes_lerc_parts_like_our_reader() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let n = 140_000;
    let cloud = common::random_cloud(n, 42, 0);
    let plain = dir.path().join("plain.tif");
    write_part(&plain, &cloud, &WriteOptions::default()).unwrap();
    let plain = Part::open(&plain).unwrap();
    let e = 0.005;
    let g = pcimg::store::tiff::zorder::Geometry::for_points(n as u64);
    assert!(g.levels() >= 2, "the test wants an overview");
    for c in [
        Compression::Lerc,
        Compression::LercDeflate,
        Compression::LercZstd,
    ] {
        let path = dir.path().join(format!("{}.tif", c.name()));
        let opts = WriteOptions {
            compression: c,
            coord_max_error: [e; 3],
            ..Default::default()
        };
        let s = write_part(&path, &cloud, &opts).unwrap();
        assert!(
            s.max_quantization_error >= e,
            "{c:?}: the bound includes LERC's"
        );
        let part = Part::open(&path).unwrap();
        assert_eq!(part.meta.codec_max_error, Some([e; 3]));
        let info = run("gdalinfo", &[path.to_str().unwrap()]);
        assert!(info.contains("COMPRESSION=LERC"), "{c:?}: {info}");
        // Limited-error tiles (x y z here) carry the LERC version libtiff
        // expects: no warning. (Lossless floating-point ones, this cloud's
        // attributes, need version 6: GDAL reads them with a warning.)
        let x = dir.path().join(format!("x-{}.tif", c.name()));
        let out = Command::new("gdal_translate")
            .args(["-b", "1", "-b", "2", "-b", "3"])
            .args([&path, &x])
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && !said.contains("Warning"),
            "{c:?}: {said}"
        );
        for level in 0..g.levels() {
            let raw = dir.path().join(format!("l{level}-{}.bin", c.name()));
            let mut opts = vec!["-of", "ENVI", "-ot", "Float32"];
            let ovr = (level as i64 - 1).to_string();
            if level > 0 {
                opts.extend(["-ovr", ovr.as_str()]);
            }
            translate(&path, &raw, &opts);
            let bytes = std::fs::read(&raw).unwrap();
            let side = g.size(level) as usize;
            assert_eq!(bytes.len(), 4 * 5 * side * side, "{c:?} level {level}");
            let bands: Vec<usize> = (0..5).collect();
            let ours = part.read_level(level, &bands).unwrap();
            let before = plain.read_level(level, &bands).unwrap();
            let points = g.level_points(level) as usize;
            assert_eq!(ours.len(), points);
            for r in 0..points {
                let (px, py) = z_pixel(r as u64);
                for band in 0..5 {
                    let at = 4 * (band * side * side + py as usize * side + px as usize);
                    let theirs = f32::from_ne_bytes(bytes[at..at + 4].try_into().unwrap());
                    let (v, was) = (ours.columns[band][r], before.columns[band][r]);
                    let at = format!("{c:?} level {level} rank {r} band {band}");
                    if band < 3 {
                        // LERC's bound, plus the f32 rounding of its result.
                        let bound = e + (was.abs() * f32::EPSILON) as f64;
                        assert!((v - was).abs() as f64 <= bound, "{at}: {v} vs {was}");
                    } else {
                        assert_eq!(v.to_bits(), was.to_bits(), "{at}");
                    }
                    // The same decoder's arithmetic: the same values.
                    assert_eq!(theirs.to_bits(), v.to_bits(), "{at}: {theirs} vs {v}");
                }
            }
        }
    }
}

#[test]
fn gdal_rewritten_file_still_opens_with_the_same_points() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), "src.tif", 200_000, Compression::None);
    let dst = dir.path().join("rewritten.tif");
    translate(
        &src,
        &dst,
        &[
            "-co",
            "TILED=YES",
            "-co",
            "COMPRESS=DEFLATE",
            "-co",
            "PREDICTOR=3",
        ],
    );
    run(
        "gdaladdo",
        &["-q", "-r", "nearest", dst.to_str().unwrap(), "2", "4"],
    );
    let a = Part::open(&src).unwrap();
    let b = Part::open(&dst).unwrap();
    assert_eq!(b.bands, a.bands);
    assert_eq!(b.levels.len(), 3);
    let all: Vec<usize> = (0..a.bands.len()).collect();
    let rows = |p: &Part, level| {
        let pts = p.read_level(level, &all).unwrap();
        let mut rows: Vec<Vec<u32>> = (0..pts.len())
            .map(|i| pts.columns.iter().map(|c| c[i].to_bits()).collect())
            .collect();
        rows.sort();
        rows
    };
    assert_eq!(
        rows(&b, 0),
        rows(&a, 0),
        "level 0 differs after GDAL's rewrite"
    );
    // GDAL's overviews are nearest-neighbour samples too: every point is real.
    let level0 = rows(&a, 0);
    for r in rows(&b, 1) {
        assert!(level0.binary_search(&r).is_ok());
    }
    assert!(
        !b.levels[1].indexed,
        "gdaladdo's overviews carry no pcimg index"
    );
}

#[test]
fn awkward_metadata_text_reads_the_same_in_gdal_and_back() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("src.tif");
    let opts = WriteOptions {
        source: Some("R&D <v2> é\x1b[2J.las".into()),
        crs: Some(r#"PROJCS["NAD83 / x",UNIT["foot",0.3048]]"#.into()),
        ..Default::default()
    };
    write_part(&src, &common::random_cloud(5_000, 7, 0), &opts).unwrap();
    let info = run("gdalinfo", &[src.to_str().unwrap()]);
    assert!(info.contains("SOURCE=R&D <v2> é\u{FFFD}[2J.las"), "{info}");
    assert!(
        !info.contains('\x1b'),
        "a control character reached GDAL's output"
    );
    assert!(
        info.contains(r#"PROJCS["NAD83 / x",UNIT["foot",0.3048]]"#),
        "{info}"
    );
    // And what GDAL writes back reads the same in pcimg.
    let dst = dir.path().join("rewritten.tif");
    translate(&src, &dst, &["-co", "TILED=YES"]);
    let (a, b) = (Part::open(&src).unwrap(), Part::open(&dst).unwrap());
    assert_eq!(b.meta.source, a.meta.source);
    assert_eq!(b.meta.crs, a.meta.crs);
    assert_eq!(b.meta.source.as_deref(), Some("R&D <v2> é\u{FFFD}[2J.las"));
}

#[test]
fn overviews_recomputed_in_place_lose_the_index() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), "src.tif", 300_000, Compression::None);
    let a = Part::open(&src).unwrap();
    assert!(a.levels.len() >= 3 && a.levels.iter().all(|l| l.indexed));
    // gdaladdo on the file itself keeps pcimg's IFDs (and their Software tag)
    // but fills the overviews with averages: no longer pcimg's points.
    run(
        "gdaladdo",
        &["-q", "-r", "average", src.to_str().unwrap(), "2", "4"],
    );
    let b = Part::open(&src).unwrap();
    assert!(b.levels[0].indexed, "level 0 is untouched");
    assert!(
        b.levels[1..].iter().all(|l| !l.indexed),
        "averaged overviews are still trusted"
    );
    // GDAL's nearest-neighbour keeps the same pixel of each block as pcimg: the
    // recomputed overviews are pcimg's own, and stay trusted.
    let src = write(dir.path(), "nn.tif", 300_000, Compression::None);
    let before = Part::open(&src).unwrap().read_level(1, &[0, 1, 2]).unwrap();
    run(
        "gdaladdo",
        &["-q", "-r", "nearest", src.to_str().unwrap(), "2", "4"],
    );
    let c = Part::open(&src).unwrap();
    assert!(c.levels.iter().all(|l| l.indexed));
    assert_eq!(c.read_level(1, &[0, 1, 2]).unwrap().columns, before.columns);
}

#[test]
fn fewer_bands_are_refused() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), "src.tif", 1000, Compression::None);
    let dst = dir.path().join("two.tif");
    translate(&src, &dst, &["-b", "1", "-b", "2"]);
    let e = Part::open(&dst).unwrap_err().to_string();
    assert!(e.contains("two.tif"), "{e}");
    assert!(e.contains("2 band") || e.contains("lists 5 bands"), "{e}");
}

#[test]
fn gdal_reads_the_paper_layout() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("paper.tif");
    let n = 300_000usize;
    let opts = WriteOptions {
        layout: pcimg::store::Layout::Paper,
        ..Default::default()
    };
    let pts = common::random_cloud(n, 42, 0);
    write_part(&path, &pts, &opts).unwrap();
    let info: serde_json::Value =
        serde_json::from_str(&run("gdalinfo", &["-json", path.to_str().unwrap()])).unwrap();
    assert_eq!(info["size"], serde_json::json!([1024, 1024]));
    assert_eq!(info["metadata"][""]["LAYOUT"], "paper");
    let origin = Part::open(&path).unwrap().meta.origin;
    // Pixel (x, y) of level k holds input point 2^k·y·1024 + 2^k·x.
    for (level, x, y) in [
        (0u32, 0u32, 0u32),
        (0, 1023, 5),
        (0, 15, 292),
        (1, 7, 3),
        (2, 255, 72),
    ] {
        let i = ((y << level) * 1024 + (x << level)) as usize;
        for (band, want) in [
            (1, pts.x[i] - origin[0]),
            (4, pts.attributes[0].values[i] as f64),
        ] {
            let mut args = vec!["-valonly".to_string(), "-b".into(), band.to_string()];
            if level > 0 {
                args.extend(["-overview".into(), level.to_string()]);
            }
            let p = path.to_str().unwrap().to_string();
            args.extend([p, (x << level).to_string(), (y << level).to_string()]);
            let out = run(
                "gdallocationinfo",
                &args.iter().map(String::as_str).collect::<Vec<_>>(),
            );
            let v: f64 = out
                .trim()
                .parse()
                .unwrap_or_else(|_| panic!("value '{out}'"));
            // gdallocationinfo prints the stored value (without the band offset).
            assert!(
                (v - want).abs() <= want.abs() * 1e-6 + 1e-3,
                "level {level} ({x}, {y}) band {band}: gdal {v}, point {i} {want}"
            );
        }
    }
    // Past the last point (row 292, column 992 onward) the pixel is nodata.
    let out = run(
        "gdallocationinfo",
        &["-valonly", "-b", "1", path.to_str().unwrap(), "1000", "292"],
    );
    assert!(out.trim().eq_ignore_ascii_case("nan"), "{out}");
}

/// The overview above a dataset's parts is made of ordinary parts: GDAL opens each
/// node with the parts' bands, and its metadata names the children it stands for.
#[test]
fn gdal_reads_overview_nodes() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("tiles");
    std::fs::create_dir(&ds).unwrap();
    for k in 0..4 {
        let mut c = common::random_cloud(30_000, 20 + k, 0);
        for x in &mut c.x {
            *x += 600.0 * k as f64;
        }
        let opts = WriteOptions::default();
        pcimg::store::write_part(&ds.join(format!("t{k}.tif")), &c, &opts).unwrap();
    }
    let o = pcimg::store::dataset::overview::IndexOptions::default();
    pcimg::store::dataset::overview::build_index(&ds, &o, &|_| {}).unwrap();
    let opened = pcimg::store::Dataset::open(&ds).unwrap();
    let nodes: Vec<&pcimg::store::Part> = opened
        .node_ids()
        .unwrap()
        .into_iter()
        .filter_map(|id| opened.part(id))
        .collect();
    assert!(!nodes.is_empty());
    for node in nodes {
        let info: serde_json::Value =
            serde_json::from_str(&run("gdalinfo", &["-json", node.path.to_str().unwrap()]))
                .unwrap();
        let names: Vec<&str> = info["bands"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b["description"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["x", "y", "z", "intensity", "gps_time"]);
        let meta = &info["metadata"][""];
        assert_eq!(
            meta["POINT_COUNT"].as_str().unwrap(),
            node.meta.point_count.to_string()
        );
        let source = meta["SOURCE"].as_str().unwrap();
        assert!(source.starts_with("pcimg overview of t"), "{source}");
    }
}

/// GDAL reads a head-first part (every IFD and value before the first tile)
/// and the same part rewritten in the older layout (IFDs after the tiles) to
/// the same checksums, every band and overview, uncompressed and compressed.
#[test]
fn gdal_reads_head_first_and_older_layouts_alike() {
    if !gdal() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for c in [Compression::None, Compression::Zstd, Compression::Deflate] {
        let new = write(dir.path(), &format!("{c:?}.tif"), 2 * 65_536 + 17, c);
        let bytes = std::fs::read(&new).unwrap();
        let w = common::tiffwalk::Walk::new(&bytes);
        assert!(w.head_end() <= w.first_tile(), "{c:?}: not head-first");
        let old = dir.path().join(format!("{c:?}-old.tif"));
        std::fs::write(&old, w.to_old_layout(&bytes)).unwrap();
        let sums = |p: &Path| -> Vec<String> {
            let info = run("gdalinfo", &["-checksum", p.to_str().unwrap()]);
            info.lines()
                .filter(|l| l.contains("Checksum=") || l.contains("Overviews checksum"))
                .map(|l| l.trim().to_string())
                .collect()
        };
        let (a, b) = (sums(&new), sums(&old));
        // 5 bands, each with its checksum and its overview's.
        assert_eq!(a.len(), 5 * 2, "{c:?}: {a:?}");
        assert_eq!(a, b, "{c:?}");
    }
}

/// A Python with GDAL's bindings (python3-gdal), for its COG validator.
fn python_with_gdal() -> Option<&'static str> {
    common::python_with("osgeo_utils.samples.validate_cloud_optimized_geotiff")
}

/// A conversion in several parts keeps every point's attributes with its own
/// coordinates, checked by software we did not write: real LAS written by laspy
/// (`fixtures/autzen_trim.laz` tiled with jitter, `bench/autzen_tiled.py`), every
/// part read back by GDAL, every attribute of every point compared with laspy's
/// (`tests/python/parts_match_las.py`).
#[test]
fn a_conversion_in_parts_equals_its_source_point_by_point_in_gdal_and_laspy() {
    let Some(py) = common::python_with("osgeo, laspy, lazrs, numpy") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let las = dir.path().join("tiled.las");
    run(
        py,
        &[
            &format!("{root}/bench/autzen_tiled.py"),
            las.to_str().unwrap(),
            "600000",
            &format!("{root}/fixtures/autzen_trim.laz"),
        ],
    );
    let out = dir.path().join("tiled.pcimg");
    // 64 MiB splits 600,000 points of 11 bands into several parts.
    run(
        env!("CARGO_BIN_EXE_pcimg"),
        &[
            "convert",
            las.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--memory",
            "64MiB",
            "-q",
        ],
    );
    let said = run(
        py,
        &[
            &format!("{root}/tests/python/parts_match_las.py"),
            las.to_str().unwrap(),
            out.to_str().unwrap(),
        ],
    );
    assert!(
        said.contains("600000 points") && said.contains("gps_time") && said.contains("all equal"),
        "{said}"
    );
}

/// GDAL's `validate_cloud_optimized_geotiff.py` accepts a part as a Cloud
/// Optimized GeoTIFF: IFDs first, then the tiles, the coarsest level's first.
#[test]
fn gdal_validates_parts_as_cloud_optimized() {
    let Some(py) = python_with_gdal() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for c in [Compression::None, Compression::Zstd, Compression::LercZstd] {
        // Three levels.
        let path = write(dir.path(), &format!("{c:?}.tif"), 5 * 65_536 + 3, c);
        let out = Command::new(py)
            .args(["-m", "osgeo_utils.samples.validate_cloud_optimized_geotiff"])
            .arg(&path)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && text.contains("is a valid cloud optimized GeoTIFF"),
            "{c:?}: {text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// The default conversion (format version 2) as GDAL sees it: every band
/// Float32 with its overview; x y z with the LAS scale as GDAL's band scale;
/// whole-number attributes with offset -2^23; and `gdal_translate -unscale
/// -ot Float64` gives every point of the source (read by pcimg's LAS reader):
/// coordinates within 1e-6 LAS units of the source's lattice points (GDAL's
/// double arithmetic), the same whole numbers exactly, attributes exactly
/// (gps_time's Float32 and the three whole numbers that make it exact).
///
/// Twice: as a small input is written (Zstd level 6), and at the level large
/// inputs get (`--zstd-level 1`), whose coordinate tiles keep Zstd's literals
/// raw.
#[test]
fn gdal_unscales_the_compact_default_to_the_source() {
    if !gdal() {
        return;
    }
    unscaled_equals_the_source(&[]);
    unscaled_equals_the_source(&["--zstd-level", "1"]);
}

fn unscaled_equals_the_source(options: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let las = std::path::PathBuf::from(format!("{root}/fixtures/autzen_trim.laz"));
    let part = dir.path().join("a.tif");
    let mut args = vec![
        "convert",
        las.to_str().unwrap(),
        "-o",
        part.to_str().unwrap(),
        "-q",
    ];
    args.extend_from_slice(options);
    run(env!("CARGO_BIN_EXE_pcimg"), &args);
    let info: serde_json::Value =
        serde_json::from_str(&run("gdalinfo", &["-json", part.to_str().unwrap()])).unwrap();
    let meta = &info["metadata"][""];
    assert_eq!(meta["PCIMG_FORMAT"], "2", "{meta}");
    assert_eq!(meta["TILE_ORDER"], "rows");
    assert_eq!(meta["LATTICE"], "0.01 0.01 0.01 0.0 0.0 0.0");
    // Every band but gps_time (8) holds whole numbers (the scan angle too:
    // LAS 1.2's whole degrees; 9 to 11 the whole numbers that make the time
    // exact).
    assert_eq!(
        meta["WHOLE_BANDS"],
        "1 2 3 4 5 6 7 9 10 11 12 13 14 15 16 17 18"
    );
    let bands = info["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 18);
    for (i, b) in bands.iter().enumerate() {
        assert_eq!(b["type"], "Float32");
        assert_eq!(
            b["overviews"].as_array().unwrap().len(),
            1,
            "band {}",
            i + 1
        );
        let scale = b["scale"].as_f64().unwrap_or(1.0);
        let offset = b["offset"].as_f64().unwrap_or(0.0);
        match i {
            0..=2 => assert_eq!(scale, 0.01),
            7 => assert_eq!(scale, 1.0),
            _ => assert_eq!((scale, offset), (1.0, -8_388_608.0), "band {}", i + 1),
        }
    }
    // Every band unscaled by GDAL, as raw doubles.
    let raw = dir.path().join("u.bin");
    translate(&part, &raw, &["-unscale", "-ot", "Float64", "-of", "ENVI"]);
    let bytes = std::fs::read(&raw).unwrap();
    let values: Vec<f64> = bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let plane = values.len() / 18;
    let band = |b: usize| &values[b * plane..(b + 1) * plane];
    let (_, src, _) = pcimg::ingest::read_all(&las, &Default::default()).unwrap();
    let n = src.x.len();
    // Rows of whole numbers: x y z on the lattice, then the attributes (gps_time
    // to a microsecond).
    let key = |c: [f64; 3], attrs: &mut dyn Iterator<Item = f64>| -> Vec<i64> {
        let mut k: Vec<i64> = c.iter().map(|v| (v / 0.01).round() as i64).collect();
        k.extend(attrs.map(|v| (v * 1e6).round() as i64));
        k
    };
    let mut ours = Vec::with_capacity(n);
    let mut worst = 0f64;
    for p in (0..plane).filter(|&p| !band(0)[p].is_nan()) {
        let c = [band(0)[p], band(1)[p], band(2)[p]];
        for v in c {
            worst = worst.max((v / 0.01 - (v / 0.01).round()).abs());
        }
        ours.push(key(c, &mut (3..18).map(|b| band(b)[p])));
    }
    assert!(
        worst < 1e-6,
        "GDAL's coordinates lie {worst} LAS units off the lattice"
    );
    let mut theirs: Vec<Vec<i64>> = (0..n)
        .map(|i| {
            key(
                [src.x[i], src.y[i], src.z[i]],
                &mut src.attributes.iter().map(|a| a.offset + a.values[i] as f64),
            )
        })
        .collect();
    ours.sort();
    theirs.sort();
    assert_eq!(ours.len(), n);
    assert!(
        ours == theirs,
        "{options:?}: GDAL's points differ from the source's"
    );
}
