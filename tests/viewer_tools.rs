//! The viewer's tools (issue 29) against scenes whose answers are known:
//! picking finds the point drawn at a pixel, a class filter hides exactly that
//! class's points, a clip box selects only the tiles that touch it, legends
//! list the classes present with their counts, turntable frames differ and go
//! round, and bad option values are refused clearly.

use pcimg::camera::Camera;
use pcimg::lod::{self, LodMode, TileCache};
use pcimg::points::{Attribute, Bounds, PointColumns};
use pcimg::render::classes::ClassMask;
use pcimg::render::cpu::CpuRasterizer;
use pcimg::render::filter::{Filter, Where};
use pcimg::render::legend;
use pcimg::render::scene::{ColorRanges, Scene, Style};
use pcimg::render::{ColorMode, PointBatch, Rasterizer, RenderOptions, pick};
use pcimg::store::{self, Dataset, WriteOptions};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

fn exe() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
    c.env("NODEVICE_SELECT", "1");
    c
}

/// `pcimg render PART` on the CPU at `size`, to `out`, with `args`.
fn render(part: &Path, size: (u32, u32), args: &[&str], out: &Path) -> std::process::Output {
    exe()
        .arg("render")
        .arg(part)
        .args(["--renderer", "cpu", "--width", &size.0.to_string()])
        .args(["--height", &size.1.to_string()])
        .args(args)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap()
}

/// A part of the synthetic scene with classes (ground 2, vegetation 5, building 6).
fn classified_part(dir: &Path, n: u64) -> PathBuf {
    let path = dir.join("scene.tif");
    store::write_part(
        &path,
        &pcimg::synth::scene_classified(n, 7),
        &WriteOptions::default(),
    )
    .unwrap();
    path
}

/// Counts of each class among the scene's first `n` points, from the generator.
fn true_counts(n: u64, seed: u64) -> [u64; 256] {
    let mut c = [0u64; 256];
    for i in 0..n {
        c[pcimg::synth::classified_point(seed, i).2 as usize] += 1;
    }
    c
}

fn all_tiles(ds: &Arc<Dataset>, level: usize) -> Vec<Arc<lod::LoadedTile>> {
    let cam = Camera::fit(&ds.bounds());
    let sel = lod::select(ds, &cam, 64, 64, LodMode::Fixed(level), u64::MAX);
    let cache = TileCache::with_bands(ds.clone(), u64::MAX, 1, vec!["classification".into()]);
    cache.load_all(&sel.tiles).unwrap()
}

#[test]
fn picking_returns_the_point_drawn_at_the_pixel() {
    // A 20 x 20 grid 1 m apart on a plane, far from the datum, and one point
    // hovering 5 m above grid point (7, 11): seen from above it hides that one.
    let origin = [637_000.0, 5_100_000.0, 300.0];
    let (mut x, mut y, mut z) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..20 {
        for j in 0..20 {
            x.push(i as f32);
            y.push(j as f32);
            z.push(0.0);
        }
    }
    x.push(7.0);
    y.push(11.0);
    z.push(5.0);
    let color: Vec<u32> = (0..x.len() as u32)
        .map(|i| 0xff00_0000 | (i * 7919))
        .collect();
    let b = PointBatch {
        origin,
        x: &x,
        y: &y,
        z: &z,
        color: &color,
    };
    let bounds = Bounds {
        min: origin,
        max: [origin[0] + 19.0, origin[1] + 19.0, origin[2] + 5.0],
    };
    let mut cam = Camera::fit(&bounds);
    cam.pitch = -89.0f64.to_radians();
    cam.yaw = 0.3;
    cam.set_clip_from_bounds(&bounds);
    let opts = RenderOptions {
        width: 400,
        height: 300,
        ..Default::default()
    };
    let frame = CpuRasterizer::new().render(&cam, &[b], &opts).unwrap();
    for (i, j) in [(0usize, 0usize), (3, 17), (19, 19), (12, 4)] {
        let k = i * 20 + j;
        let p = [origin[0] + i as f64, origin[1] + j as f64, origin[2]];
        let [sx, sy] = cam.project(p, 400, 300).unwrap();
        let hit = pick::pick(&cam, &[b], &opts, sx as u32, sy as u32, 0)
            .unwrap()
            .unwrap();
        assert_eq!((hit.batch, hit.index), (0, k), "grid point ({i}, {j})");
        assert_eq!(hit.position, p);
        // The picked point's colour is the one the frame shows there.
        let px = frame.pixel(hit.pixel.0, hit.pixel.1).unwrap();
        let c = color[k];
        assert_eq!(px[..3], [c as u8, (c >> 8) as u8, (c >> 16) as u8]);
    }
    // The hovering point hides grid point (7, 11) and is the one picked.
    let p = [origin[0] + 7.0, origin[1] + 11.0, origin[2] + 5.0];
    let [sx, sy] = cam.project(p, 400, 300).unwrap();
    let hit = pick::pick(&cam, &[b], &opts, sx as u32, sy as u32, 0)
        .unwrap()
        .unwrap();
    assert_eq!(hit.index, 400);
    // Between grid points, the radius finds the nearest drawn pixel.
    let near = pick::pick(&cam, &[b], &opts, sx as u32 + 2, sy as u32, 4)
        .unwrap()
        .unwrap();
    assert_eq!(near.index, 400);
    // Nothing out in the background.
    assert_eq!(pick::pick(&cam, &[b], &opts, 0, 0, 2).unwrap(), None);
    assert!(pick::pick(&cam, &[b], &opts, 400, 0, 0).is_err());
    // Hidden points (NaN height: a filter) are never picked: the grid point
    // under the hovering one is found once it is hidden.
    let mut zh = z.clone();
    zh[400] = f32::NAN;
    let hb = PointBatch { z: &zh, ..b };
    let gone = pick::pick(&cam, &[hb], &opts, sx as u32, sy as u32, 0).unwrap();
    assert!(gone.is_none_or(|h| h.index != 400));
    let base = [origin[0] + 7.0, origin[1] + 11.0, origin[2]];
    let [bx, by] = cam.project(base, 400, 300).unwrap();
    let hit = pick::pick(&cam, &[hb], &opts, bx as u32, by as u32, 0)
        .unwrap()
        .unwrap();
    assert_eq!(hit.index, 7 * 20 + 11);
}

#[test]
fn render_pick_prints_the_point_with_every_attribute() {
    let dir = tempfile::tempdir().unwrap();
    // Nine points on a 3 x 3 grid 10 m apart, each with its own attributes.
    let mut c = PointColumns {
        attributes: vec![
            Attribute::new("intensity", Vec::new()),
            Attribute::new("classification", Vec::new()),
            Attribute {
                name: "gps_time".into(),
                offset: 3.0e8,
                values: Vec::new(),
            },
        ],
        ..Default::default()
    };
    for k in 0..9 {
        c.x.push(500_000.0 + 10.0 * (k % 3) as f64);
        c.y.push(4_000_000.0 + 10.0 * (k / 3) as f64);
        c.z.push(100.0 + k as f64);
        c.attributes[0].values.push(1000.0 + k as f32);
        c.attributes[1].values.push(if k == 4 { 6.0 } else { 2.0 });
        c.attributes[2].values.push(k as f32 * 0.5);
    }
    let part = dir.path().join("grid.tif");
    store::write_part(&part, &c, &WriteOptions::default()).unwrap();
    let ds = Dataset::open(&part).unwrap();
    let cam = Camera::fit(&ds.bounds());
    // Where the centre point (k = 4) lands on a 320 x 240 frame.
    let [sx, sy] = cam
        .project([500_010.0, 4_000_010.0, 104.0], 320, 240)
        .unwrap();
    let at = format!("{},{}", sx as u32, sy as u32);
    let o = render(
        &part,
        (320, 240),
        &["--point-size", "3", "--pick", &at],
        &dir.path().join("f.png"),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!((v["x"].as_f64().unwrap() - 500_010.0).abs() < 1e-3, "{v}");
    assert!((v["y"].as_f64().unwrap() - 4_000_010.0).abs() < 1e-3, "{v}");
    assert!((v["z"].as_f64().unwrap() - 104.0).abs() < 1e-3, "{v}");
    assert_eq!(v["attributes"]["intensity"], 1004.0);
    assert_eq!(v["attributes"]["classification"], 6.0);
    assert!((v["attributes"]["gps_time"].as_f64().unwrap() - 300_000_002.0).abs() < 1e-3);
    assert_eq!(v["class_name"], "building");
    // A pixel in the empty corner: null.
    let o = render(
        &part,
        (320, 240),
        &["--pick", "0,0"],
        &dir.path().join("g.png"),
    );
    assert!(o.status.success());
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "null");
}

#[test]
fn class_counts_are_recorded_and_a_class_filter_hides_exactly_that_class() {
    let dir = tempfile::tempdir().unwrap();
    let n = 200_000;
    let part = classified_part(dir.path(), n);
    let ds = Arc::new(Dataset::open(&part).unwrap());
    let truth = true_counts(n, 7);
    // Recorded at conversion: the legend lists the classes present, with counts.
    let entries = legend::class_entries(&ds, &ClassMask::default());
    let listed: Vec<(u8, u64)> = entries.iter().map(|e| (e.code, e.count)).collect();
    let want: Vec<(u8, u64)> = (0..256)
        .filter(|&c| truth[c] > 0)
        .map(|c| (c as u8, truth[c]))
        .collect();
    assert_eq!(listed, want);
    assert_eq!(want.len(), 3, "ground, vegetation and building");
    assert_eq!(entries[2].name, "building");
    // Level 0 holds every point: hiding buildings removes exactly their count.
    let tiles = all_tiles(&ds, 0);
    let total: u64 = tiles.iter().map(|t| t.len() as u64).sum();
    assert_eq!(total, n);
    let ranges = ColorRanges::from_tiles(&tiles, &ds.bounds());
    let style = Style::of(ColorMode::Classification);
    let f = Filter {
        classes: ClassMask::new(None, &[6]),
        ..Filter::default()
    };
    let scene = Scene::build(tiles.clone(), &style, &ranges, &f);
    assert_eq!(scene.shown_points(), n - truth[6]);
    let only = Filter {
        classes: ClassMask::new(Some(&[5]), &[]),
        ..Filter::default()
    };
    let scene = Scene::build(tiles.clone(), &style, &ranges, &only);
    assert_eq!(scene.shown_points(), truth[5]);
    // Every hidden point is of the hidden class, every shown one is not.
    for (t, h) in scene.tiles.iter().zip(&scene.hidden) {
        let cls = t.attribute("classification").unwrap();
        let h = h.as_ref().unwrap();
        for (c, z) in cls.iter().zip(h) {
            assert_eq!(*c == 5.0, !z.is_nan());
        }
    }
    // A band range: z within 30..40 m (absolute), counted directly.
    let w = Filter {
        wheres: vec![Where::parse("z=30..40").unwrap()],
        ..Filter::default()
    };
    let scene = Scene::build(tiles.clone(), &style, &ranges, &w);
    let direct: u64 = tiles
        .iter()
        .map(|t| {
            t.z.iter()
                .filter(|&&z| (30.0..=40.0).contains(&(z as f64 + t.origin[2])))
                .count() as u64
        })
        .sum();
    assert!(direct > 0 && direct < n);
    assert_eq!(scene.shown_points(), direct);
    // Drawn: with only buildings, every lit pixel is the building colour.
    let cam = Camera::fit(&ds.bounds());
    let only6 = Filter {
        classes: ClassMask::new(Some(&[6]), &[]),
        ..Filter::default()
    };
    let scene = Scene::build(tiles, &style, &ranges, &only6);
    let frame = CpuRasterizer::new()
        .render(
            &cam,
            &scene.batches(),
            &RenderOptions {
                width: 320,
                height: 240,
                ..Default::default()
            },
        )
        .unwrap();
    let b = pcimg::render::color::unpack_rgb(pcimg::render::classes::color(6));
    let lit: Vec<&[u8]> = frame
        .rgba
        .chunks(4)
        .filter(|p| p[..3] != [0, 0, 0])
        .collect();
    assert!(lit.len() > 1000);
    assert!(lit.iter().all(|p| p[..3] == b));
}

#[test]
fn legends_sum_class_counts_over_parts() {
    let dir = tempfile::tempdir().unwrap();
    let c = pcimg::synth::scene_classified(120_000, 7);
    // Two parts: the west and east halves of the scene.
    let mid = pcimg::synth::SCENE_ORIGIN[0] + pcimg::synth::SCENE_SIZE / 2.0;
    let mut halves = [c.empty_like(), c.empty_like()];
    let mut want = [[0u64; 256]; 2];
    for i in 0..c.len() {
        let h = (c.x[i] >= mid) as usize;
        halves[h].append_range(&c, i, i + 1);
        want[h][c.attributes[1].values[i] as usize] += 1;
    }
    std::fs::create_dir(dir.path().join("ds")).unwrap();
    for (k, h) in halves.iter().enumerate() {
        let p = dir.path().join(format!("ds/part{k}.tif"));
        store::write_part(&p, h, &WriteOptions::default()).unwrap();
        let one = Dataset::open(&p).unwrap();
        let recorded: Vec<(u8, u64)> = one.parts().unwrap()[0].meta.class_counts.clone();
        let truth: Vec<(u8, u64)> = (0..256)
            .filter(|&c| want[k][c] > 0)
            .map(|c| (c as u8, want[k][c]))
            .collect();
        assert_eq!(recorded, truth, "part {k}");
    }
    let ds = Dataset::open(&dir.path().join("ds")).unwrap();
    assert_eq!(ds.part_count(), 2);
    let hidden = ClassMask::new(None, &[2]);
    let e = legend::class_entries(&ds, &hidden);
    for x in &e {
        assert_eq!(x.count, want[0][x.code as usize] + want[1][x.code as usize]);
        assert_eq!(x.shown, x.code != 2);
    }
    assert_eq!(e.iter().map(|x| x.count).sum::<u64>(), 120_000);
}

#[test]
fn a_clip_box_selects_only_the_tiles_that_touch_it() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 400_000);
    let ds = Arc::new(Dataset::open(&part).unwrap());
    let b = ds.bounds();
    let cam = Camera::fit(&b);
    // A slab 8 m thick across x through the middle of the scene.
    let cx = (b.min[0] + b.max[0]) / 2.0;
    let clip = Bounds {
        min: [cx - 4.0, b.min[1], b.min[2]],
        max: [cx + 4.0, b.max[1], b.max[2]],
    };
    let all = lod::select(&ds, &cam, 640, 480, LodMode::Fixed(0), u64::MAX);
    let some = lod::select_clipped(
        &ds,
        &cam,
        640,
        480,
        LodMode::Fixed(0),
        u64::MAX,
        Some(&clip),
    );
    let touching: Vec<_> = all
        .tiles
        .iter()
        .filter(|t| t.bounds.intersects(&clip))
        .collect();
    assert!(!touching.is_empty() && touching.len() < all.tiles.len());
    assert_eq!(some.tiles.len(), touching.len());
    assert!(some.tiles.iter().all(|t| t.bounds.intersects(&clip)));
    assert!(some.points < all.points);
    // View-dependent selection spends its budget inside the clip too.
    let v = lod::select_clipped(
        &ds,
        &cam,
        640,
        480,
        LodMode::View { budget: 1 << 20 },
        u64::MAX,
        Some(&clip),
    );
    assert!(v.tiles.iter().all(|t| t.bounds.intersects(&clip)));
    // The drawn points all lie in the box.
    let cache = TileCache::new(ds.clone(), u64::MAX, 1);
    let tiles = cache.load_all(&some.tiles).unwrap();
    let f = Filter {
        clip: Some(clip),
        ..Filter::default()
    };
    let ranges = ColorRanges::from_tiles(&tiles, &b);
    let scene = Scene::build(tiles, &Style::default(), &ranges, &f);
    let mut inside = 0u64;
    for (t, h) in scene.tiles.iter().zip(&scene.hidden) {
        let z = h.as_deref().unwrap_or(&t.z);
        for (zi, xi) in z.iter().zip(&t.x) {
            if zi.is_nan() {
                continue;
            }
            inside += 1;
            let x = *xi as f64 + t.origin[0];
            assert!(x >= clip.min[0] && x <= clip.max[0]);
        }
    }
    assert!(inside > 0);
    // As many as lie in the box by their own coordinates, counted here from the
    // tiles (not from the filter's hidden heights).
    let in_box = |p: [f64; 3]| (0..3).all(|a| p[a] >= clip.min[a] && p[a] <= clip.max[a]);
    let truth: usize = scene
        .tiles
        .iter()
        .map(|t| {
            (0..t.len())
                .filter(|&i| {
                    in_box([
                        t.x[i] as f64 + t.origin[0],
                        t.y[i] as f64 + t.origin[1],
                        t.z[i] as f64 + t.origin[2],
                    ])
                })
                .count()
        })
        .sum();
    assert_eq!(inside, truth as u64);
}

#[test]
fn turntable_frames_differ_and_go_round() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 60_000);
    let run = |view: &str, extra: &[&str], out: &Path| {
        let o = exe()
            .arg("render")
            .arg(&part)
            .args(["--renderer", "cpu", "--width", "160", "--height", "120"])
            .args(["--view", view])
            .args(extra)
            .arg("-o")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let pattern = dir.path().join("spin_{}.png");
    run("0,-30", &["--turntable", "8"], &pattern);
    let frames: Vec<Vec<u8>> = (0..8)
        .map(|i| {
            image::open(dir.path().join(format!("spin_{i:03}.png")))
                .unwrap()
                .to_rgba8()
                .into_raw()
        })
        .collect();
    assert!(!dir.path().join("spin_008.png").exists());
    for i in 0..8 {
        for j in i + 1..8 {
            assert_ne!(frames[i], frames[j], "frames {i} and {j} are the same");
        }
    }
    // Frame 0 is the view asked for, frame 4 the view from the other side
    // (yaw + 180°): the same as asking for it.
    for (k, view) in [(0, "0,-30"), (4, "180,-30"), (2, "90,-30")] {
        let one = dir.path().join(format!("one{k}.png"));
        run(view, &[], &one);
        assert_eq!(
            image::open(&one).unwrap().to_rgba8().into_raw(),
            frames[k],
            "frame {k} vs --view {view}"
        );
    }
    // One animated PNG: 8 frames, each the size asked for.
    let apng = dir.path().join("spin.png");
    run("0,-30", &["--turntable", "8"], &apng);
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&apng).unwrap()));
    let mut r = dec.read_info().unwrap();
    let actl = r.info().animation_control.unwrap();
    assert_eq!(actl.num_frames, 8);
    let mut buf = vec![0u8; r.output_buffer_size().unwrap()];
    let mut decoded = Vec::new();
    while let Ok(info) = r.next_frame(&mut buf) {
        assert_eq!((info.width, info.height), (160, 120));
        decoded.push(buf[..info.buffer_size()].to_vec());
    }
    assert_eq!(decoded.len(), 8);
    assert_eq!(decoded[3], frames[3]);
}

#[test]
fn bad_values_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 5_000);
    // A part without classes.
    let plain = dir.path().join("plain.tif");
    store::write_part(
        &plain,
        &pcimg::synth::scene(5_000, 1),
        &WriteOptions::default(),
    )
    .unwrap();
    let out = dir.path().join("x.png");
    for (path, args, says) in [
        (&part, vec!["--color", "band:nope"], "no band 'nope'"),
        (&part, vec!["--classes", "2,300"], "class codes 0 to 255"),
        (
            &part,
            vec!["--exclude-classes", "x"],
            "class codes 0 to 255",
        ),
        (&part, vec!["--where", "z"], "NAME=VALUE"),
        (&part, vec!["--where", "z=5..1"], "low end lies above"),
        (&part, vec!["--where", "nope=1"], "no band 'nope'"),
        (&part, vec!["--clip", "1,2,3"], "six"),
        (&part, vec!["--clip", "0,0,9,1,1,1"], "minimum lies above"),
        (
            &part,
            vec!["--color", "height", "--range", "5,1"],
            "LO below HI",
        ),
        (
            &part,
            vec!["--color", "height", "--ramp", "rainbow"],
            "unknown ramp",
        ),
        (&part, vec!["--ramp", "gray"], "apply to --color intensity"),
        (&part, vec!["--pick", "999,1"], "a pixel of the"),
        (&part, vec!["--edl-strength", "99"], "0.1 to 10"),
        (&plain, vec!["--classes", "2"], "no band 'classification'"),
        (
            &plain,
            vec!["--color", "classification"],
            "no band 'classification'",
        ),
    ] {
        let o = exe()
            .arg("render")
            .arg(path)
            .args(["--renderer", "cpu", "--width", "64", "--height", "48", "-o"])
            .arg(&out)
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn ramps_legends_and_edl_options_draw() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 50_000);
    let render = |args: &[&str]| -> image::RgbaImage {
        let out = dir.path().join("r.png");
        let o = exe()
            .arg("render")
            .arg(&part)
            .args([
                "--renderer",
                "cpu",
                "--width",
                "320",
                "--height",
                "240",
                "-o",
            ])
            .arg(&out)
            .args(args)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        image::open(&out).unwrap().to_rgba8()
    };
    let plain = render(&["--color", "band:intensity"]);
    let gray = render(&["--color", "band:intensity", "--ramp", "gray"]);
    let fixed = render(&["--color", "band:intensity", "--range", "0,1000"]);
    assert_ne!(plain, gray);
    assert_ne!(plain, fixed);
    // The legend is drawn in the top-right corner, the scale bar bottom-left.
    let legend = render(&["--color", "band:intensity", "--legend"]);
    let differs = |x0: u32, y0: u32, x1: u32, y1: u32| {
        (y0..y1).any(|y| (x0..x1).any(|x| legend.get_pixel(x, y) != plain.get_pixel(x, y)))
    };
    assert!(differs(220, 0, 320, 100), "no legend");
    assert!(differs(0, 200, 100, 240), "no scale bar");
    // EDL: the options turn it on and change the shading.
    let edl1 = render(&["--color", "height", "--edl"]);
    let edl2 = render(&[
        "--color",
        "height",
        "--edl-strength",
        "4",
        "--edl-radius",
        "3",
    ]);
    let none = render(&["--color", "height"]);
    assert_ne!(edl1, none);
    assert_ne!(edl1, edl2);
}

#[test]
fn the_summary_says_the_points_loaded_and_those_the_filter_kept() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 50_000);
    let png = dir.path().join("f.png");
    let summary = |args: &[&str]| {
        let o = render(&part, (160, 120), args, &png);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        // (The summary goes to stderr, beside "wrote …".)
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    // Every point loaded (level 0); the filter keeps the buildings, counted
    // from the generator.
    let buildings = true_counts(50_000, 7)[6];
    assert!(buildings > 0 && buildings < 50_000);
    let out = summary(&["--classes", "6", "--lod", "0"]);
    assert!(
        out.contains("50,000 points from")
            && out.contains(&format!(
                "{} kept by the filter",
                pcimg::text::count(buildings)
            )),
        "{out}"
    );
    // Without a filter nothing is said about keeping.
    let out = summary(&["--lod", "0"]);
    assert!(
        out.contains("50,000 points from") && !out.contains("kept"),
        "{out}"
    );
}

#[test]
fn filters_hide_the_same_points_on_the_gpu() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 50_000);
    let args = [
        "--color",
        "classification",
        "--classes",
        "6",
        "--view",
        "30,-40",
    ];
    let cpu = dir.path().join("cpu.png");
    let o = render(&part, (320, 240), &args, &cpu);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let gpu = dir.path().join("gpu.png");
    let o = exe()
        .arg("render")
        .arg(&part)
        .args(["--renderer", "gpu", "--width", "320", "--height", "240"])
        .args(args)
        .arg("-o")
        .arg(&gpu)
        .output()
        .unwrap();
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("no GPU adapter") && std::env::var("CI").ok().as_deref() != Some("true"),
            "{err}"
        );
        eprintln!("note: skipping, no wgpu adapter: {err}");
        return;
    }
    let (c, g) = (
        image::open(&cpu).unwrap().to_rgba8(),
        image::open(&gpu).unwrap().to_rgba8(),
    );
    let building = pcimg::render::color::unpack_rgb(pcimg::render::classes::color(6));
    let lit = |i: &image::RgbaImage| i.pixels().filter(|p| p[0] | p[1] | p[2] != 0).count();
    assert!(lit(&g) > 1000);
    assert!(
        g.pixels()
            .all(|p| p[0] | p[1] | p[2] == 0 || p.0[..3] == building)
    );
    let same = c.pixels().zip(g.pixels()).filter(|(a, b)| a == b).count();
    assert!(same as f64 > 0.99 * (320.0 * 240.0), "{same}");
}

#[test]
fn the_cpu_rasterizer_keeps_the_point_that_won_each_pixel() {
    use pcimg::render::cpu::CpuStrategy;
    for strategy in [CpuStrategy::PerThread, CpuStrategy::SharedAtomic] {
        let mut r = CpuRasterizer::with_strategy(strategy);
        kept_ids_are_the_points_drawn(&mut r, &format!("{strategy:?}"), true);
    }
}

/// The id-buffer test scene: a 20 x 20 grid 1 m apart far from the datum;
/// point 400 hovers 5 m above grid point (7, 11) and hides it; points 401 and
/// 402 lie at the same place (3, 3, 2): a depth tie the smaller colour (402's)
/// wins; 403 and 404 tie with the same colour too, at (15, 5, 2): the smaller
/// index wins; point 405 lies behind grid point (12, 4) on the ray from the
/// eye: occluded. `exact`: the renderer resolves like the CPU one (64-bit
/// depth and colour), so every pixel's id agrees with picking by projection.
fn kept_ids_are_the_points_drawn(r: &mut dyn Rasterizer, label: &str, exact: bool) {
    let origin = [637_000.0, 5_100_000.0, 300.0];
    let (mut x, mut y, mut z) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..20 {
        for j in 0..20 {
            x.push(i as f32);
            y.push(j as f32);
            z.push(0.0);
        }
    }
    for (px, py, pz) in [(7.0, 11.0, 5.0), (3.0, 3.0, 2.0), (3.0, 3.0, 2.0)] {
        x.push(px);
        y.push(py);
        z.push(pz);
    }
    for _ in 0..2 {
        x.push(15.0);
        y.push(5.0);
        z.push(2.0);
    }
    let bounds = Bounds {
        min: origin,
        max: [origin[0] + 19.0, origin[1] + 19.0, origin[2] + 5.0],
    };
    let mut cam = Camera::fit(&bounds);
    cam.pitch = -80.0f64.to_radians();
    cam.yaw = 0.3;
    cam.set_clip_from_bounds(&bounds);
    let eye = cam.eye().to_array();
    let front = [origin[0] + 12.0, origin[1] + 4.0, origin[2]];
    let behind: [f64; 3] = std::array::from_fn(|a| eye[a] + (front[a] - eye[a]) * 1.05);
    x.push((behind[0] - origin[0]) as f32);
    y.push((behind[1] - origin[1]) as f32);
    z.push((behind[2] - origin[2]) as f32);
    let mut color: Vec<u32> = (0..x.len() as u32)
        .map(|i| 0xff00_0000 | (i * 7919 + 17))
        .collect();
    color[401] = 0xff00_ff00;
    color[402] = 0xff00_00ff;
    color[403] = 0xff12_3456;
    color[404] = 0xff12_3456;
    let b = PointBatch {
        origin,
        x: &x,
        y: &y,
        z: &z,
        color: &color,
    };
    // An empty batch first: ids name their batch.
    let none = PointBatch {
        origin,
        x: &[],
        y: &[],
        z: &[],
        color: &[],
    };
    let batches = [none, b];
    let id = |i: usize| pick::point_id(1, i);
    for (size, edl) in [(1, false), (3, true)] {
        let opts = RenderOptions {
            width: 400,
            height: 300,
            point_size: size,
            eye_dome_lighting: edl,
            ..Default::default()
        };
        let what = format!("{label}, size {size}");
        // Off: no id buffer, nothing to read.
        r.keep_ids(false);
        r.render(&cam, &batches, &opts).unwrap();
        assert!(r.last_ids().is_none(), "{what}");
        assert!(r.keep_ids(true));
        let frame = r.render(&cam, &batches, &opts).unwrap();
        let ids = r.last_ids().unwrap().to_vec();
        assert_eq!(ids.len(), 400 * 300);
        let at = |p: [f64; 3]| {
            let [sx, sy] = cam.project(p, 400, 300).unwrap();
            let h = pick::from_ids(&ids, &batches, 400, 300, sx as u32, sy as u32, 0)
                .unwrap()
                .unwrap();
            assert_eq!(h.position, p, "{what}");
            assert_eq!(h.batch, 1, "{what}");
            h.index
        };
        let world = |i: usize| {
            [
                origin[0] + x[i] as f64,
                origin[1] + y[i] as f64,
                origin[2] + z[i] as f64,
            ]
        };
        for (i, j) in [(0usize, 0usize), (3, 17), (19, 19), (12, 4)] {
            assert_eq!(at(world(i * 20 + j)), i * 20 + j, "{what}");
        }
        assert_eq!(at(world(400)), 400, "the hovering point: {what}");
        assert_eq!(at(world(401)), 402, "a depth tie: the colour drawn: {what}");
        assert_eq!(at(world(403)), 403, "a full tie: the smaller index: {what}");
        // Every pixel agrees with the frame (and, where the renderer resolves
        // like the CPU one, with picking by projection).
        let mut drawn = 0;
        for py in (0..300).step_by(7) {
            for px in (0..400).step_by(5) {
                let got = ids[py * 400 + px];
                if exact {
                    let by_proj =
                        pick::pick(&cam, &batches, &opts, px as u32, py as u32, 0).unwrap();
                    assert_eq!(
                        by_proj.map(|h| pick::point_id(h.batch, h.index)),
                        (got != pick::NO_POINT).then_some(got),
                        "pixel ({px}, {py}): {what}"
                    );
                }
                if got != pick::NO_POINT && !edl {
                    drawn += 1;
                    assert_eq!(got >> 32, 1);
                    let c = color[(got & 0xffff_ffff) as usize];
                    let shown = frame.pixel(px as u32, py as u32).unwrap();
                    let want = [c as u8, (c >> 8) as u8, (c >> 16) as u8];
                    if exact {
                        assert_eq!(shown[..3], want, "pixel ({px}, {py}): {what}");
                    } else {
                        // BGR565: the top 5, 6, 5 bits.
                        let top = |v: u8, bits: u32| v >> (8 - bits);
                        assert_eq!(
                            [top(shown[0], 5), top(shown[1], 6), top(shown[2], 5)],
                            [top(want[0], 5), top(want[1], 6), top(want[2], 5)],
                            "pixel ({px}, {py}): {what}"
                        );
                    }
                }
            }
        }
        assert!(edl || drawn > 0, "{what}");
        // Every point but the hidden, occluded and tie-losing ones shows.
        let distinct: std::collections::HashSet<u64> = ids
            .iter()
            .copied()
            .filter(|&i| i != pick::NO_POINT)
            .collect();
        assert!(distinct.len() >= 395, "{what}: {} points", distinct.len());
        // An occluded point is never picked: 405 appears in no pixel, nor
        // do the losers of the ties.
        assert_eq!(at(world(12 * 20 + 4)), 12 * 20 + 4);
        assert!(!ids.contains(&id(405)), "{what}");
        assert!(!ids.contains(&id(401)), "{what}");
        assert!(!ids.contains(&id(404)), "{what}");
        // Background: none.
        assert_eq!(
            pick::from_ids(&ids, &batches, 400, 300, 0, 0, 2).unwrap(),
            None
        );
        assert!(pick::from_ids(&ids, &batches, 400, 300, 400, 0, 0).is_err());
        assert!(pick::from_ids(&ids[1..], &batches, 400, 300, 0, 0, 0).is_err());
    }
    r.keep_ids(false);
    r.render(&cam, &batches, &RenderOptions::default()).unwrap();
    assert!(r.last_ids().is_none(), "{label}");
}

#[test]
fn a_slab_draws_only_the_points_within_it_and_loads_only_the_tiles_it_crosses() {
    use pcimg::render::filter::{Slab, parse_slab};
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 400_000);
    let ds = Arc::new(Dataset::open(&part).unwrap());
    let b = ds.bounds();
    let cam = Camera::fit(&b);
    // A vertical plane at 30° through the centre, 6 m thick.
    let c = b.center();
    let (s30, c30) = 30f64.to_radians().sin_cos();
    let slab = Slab::new(c, [c30, s30, 0.0], 6.0).unwrap();
    let f = Filter {
        slab: Some(slab),
        ..Filter::default()
    };
    let all = lod::select(&ds, &cam, 640, 480, LodMode::Fixed(0), u64::MAX);
    let some = lod::select_region(&ds, &cam, 640, 480, LodMode::Fixed(0), u64::MAX, &|t| {
        f.may_show(t)
    });
    assert!(!some.tiles.is_empty() && some.tiles.len() < all.tiles.len());
    assert!(some.tiles.iter().all(|t| slab.touches(&t.bounds)));
    // Count, over every point, those within the slab: all lie in the tiles
    // kept, and exactly those are drawn.
    let cache = TileCache::new(ds.clone(), u64::MAX, 1);
    let every = cache.load_all(&all.tiles).unwrap();
    let world = |t: &lod::LoadedTile, i: usize| {
        [
            t.x[i] as f64 + t.origin[0],
            t.y[i] as f64 + t.origin[1],
            t.z[i] as f64 + t.origin[2],
        ]
    };
    let within: u64 = every
        .iter()
        .map(|t| (0..t.len()).filter(|&i| slab.contains(world(t, i))).count() as u64)
        .sum();
    assert!(within > 0 && within < 400_000 / 10, "{within}");
    let tiles = cache.load_all(&some.tiles).unwrap();
    let ranges = ColorRanges::from_tiles(&tiles, &b);
    let scene = Scene::build(tiles, &Style::default(), &ranges, &f);
    assert_eq!(scene.shown_points(), within);
    for (t, h) in scene.tiles.iter().zip(&scene.hidden) {
        let z = h.as_deref().unwrap();
        for (i, zi) in z.iter().enumerate() {
            assert_eq!(!zi.is_nan(), slab.contains(world(t, i)));
        }
    }
    // The same from the command line: drawn from the side, a pick in the
    // middle of the profile finds a point within the slab.
    let arg = format!("{},{},{},{c30},{s30},0,6", c[0], c[1], c[2]);
    assert_eq!(parse_slab(&arg).unwrap().normal, slab.normal);
    let png = dir.path().join("slab.png");
    let o = render(&part, (320, 240), &["--slab", &arg], &png);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&png).unwrap().to_rgb8();
    let lit: Vec<(u32, u32)> = img
        .enumerate_pixels()
        .filter(|(_, _, p)| p.0 != [0, 0, 0])
        .map(|(x, y, _)| (x, y))
        .collect();
    assert!(!lit.is_empty(), "the profile shows the slab's points");
    for &(px, py) in lit.iter().step_by(lit.len().div_ceil(4)) {
        let o = render(
            &part,
            (320, 240),
            &["--slab", &arg, "--pick", &format!("{px},{py}")],
            &dir.path().join("pick.png"),
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let p = ["x", "y", "z"].map(|k| v[k].as_f64().unwrap());
        assert!(slab.distance(p).abs() <= 3.0 + 1e-3, "{v}");
    }
    let o = render(
        &part,
        (64, 48),
        &["--slab", "0,0,0,0,0,0,1"],
        &dir.path().join("bad.png"),
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--slab"));
}

/// A GPU rasterizer, or `None` (a note, and a failure under `CI=true`) when
/// this machine has no wgpu adapter.
fn gpu_or_skip(opts: pcimg::render::gpu::GpuOptions) -> Option<pcimg::render::gpu::GpuRasterizer> {
    match pcimg::render::gpu::GpuRasterizer::with_options(opts) {
        Ok(g) => Some(g),
        Err(e) => {
            assert!(
                std::env::var("CI").ok().as_deref() != Some("true"),
                "no wgpu adapter under CI: {e}"
            );
            eprintln!("note: skipping, no wgpu adapter: {e}");
            None
        }
    }
}

#[test]
fn the_gpu_rasterizer_keeps_the_point_that_won_each_pixel() {
    use pcimg::render::gpu::GpuOptions;
    let Some(mut gpu) = gpu_or_skip(GpuOptions::default()) else {
        return;
    };
    // The 64-bit framebuffer resolves like the CPU: every pixel must agree.
    let exact = gpu.has_int64_atomics();
    let name = gpu.name();
    kept_ids_are_the_points_drawn(&mut gpu, &name, exact);
    // The 32-bit fallback (16-bit log depth, BGR565) keeps its own winners.
    let Some(mut g32) = gpu_or_skip(GpuOptions {
        force_32bit_atomics: true,
        ..GpuOptions::default()
    }) else {
        return;
    };
    let name = g32.name();
    kept_ids_are_the_points_drawn(&mut g32, &name, false);
}

#[test]
fn render_pick_agrees_between_the_gpu_and_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let part = classified_part(dir.path(), 50_000);
    let pick = |renderer: &str, at: &str| {
        let o = exe()
            .arg("render")
            .arg(&part)
            .args(["--renderer", renderer, "--width", "320", "--height", "240"])
            .args(["--point-size", "2", "--view", "30,-40", "--pick", at, "-o"])
            .arg(dir.path().join(format!("{renderer}.png")))
            .output()
            .unwrap();
        (
            o.status.success(),
            o.stdout,
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let mut hits = 0;
    for at in ["160,120", "100,90", "230,150", "5,5"] {
        let (ok, cpu, err) = pick("cpu", at);
        assert!(ok, "{err}");
        let (ok, gpu, err) = pick("gpu", at);
        if !ok {
            assert!(
                err.contains("no GPU adapter")
                    && std::env::var("CI").ok().as_deref() != Some("true"),
                "{err}"
            );
            eprintln!("note: skipping, no wgpu adapter: {err}");
            return;
        }
        let (c, g): (serde_json::Value, serde_json::Value) = (
            serde_json::from_slice(&cpu).unwrap(),
            serde_json::from_slice(&gpu).unwrap(),
        );
        assert_eq!(c, g, "--pick {at}");
        hits += !c.is_null() as usize;
    }
    assert!(hits >= 2, "{hits} of the pixels hit a point");
}
