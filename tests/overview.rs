//! The dataset index and the overview above the parts (issue 26): a dataset of many
//! small parts drawn from the top covers what the single-part dataset of the same
//! points covers, under a budget its parts' coarsest tiles alone would exceed; the
//! index notices a removed, replaced or unlisted part; old datasets still open;
//! selection keeps the budget and never leaves a visible part out.

mod common;

use pcimg::camera::{self, Camera, Containment};
use pcimg::lod::{self, LodMode};
use pcimg::points::{Attribute, Bounds, PointColumns};
use pcimg::store::dataset::overview::{IndexOptions, build_index};
use pcimg::store::{Dataset, WriteOptions, write_part};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A terrain of `n` points over 600 × 400 units: a tilted plane with bumps, and
/// intensity.
fn terrain(n: usize, seed: u64) -> PointColumns {
    let mut r = pcimg::synth::Rng::new(seed);
    let mut c = PointColumns {
        attributes: vec![Attribute::new("intensity", Vec::new())],
        ..Default::default()
    };
    for _ in 0..n {
        let (x, y) = (r.f64() * 600.0, r.f64() * 400.0);
        c.x.push(500_000.0 + x);
        c.y.push(4_000_000.0 + y);
        c.z.push(100.0 + 0.05 * x + 3.0 * (x / 40.0).sin() * (y / 30.0).cos());
        c.attributes[0].values.push((r.f64() * 255.0) as f32);
    }
    c
}

/// The points of `c` whose x and y fall in grid cell (`i`, `j`) of `nx` × `ny`.
fn cell(c: &PointColumns, nx: usize, ny: usize, i: usize, j: usize) -> PointColumns {
    let mut out = PointColumns {
        attributes: vec![Attribute::new("intensity", Vec::new())],
        ..Default::default()
    };
    for k in 0..c.len() {
        let ci = (((c.x[k] - 500_000.0) / 600.0 * nx as f64) as usize).min(nx - 1);
        let cj = (((c.y[k] - 4_000_000.0) / 400.0 * ny as f64) as usize).min(ny - 1);
        if (ci, cj) == (i, j) {
            out.x.push(c.x[k]);
            out.y.push(c.y[k]);
            out.z.push(c.z[k]);
            out.attributes[0].values.push(c.attributes[0].values[k]);
        }
    }
    out
}

/// A directory of `nx` × `ny` parts made separately (as tiles of a survey are),
/// indexed; and the single part of the same points.
fn datasets(dir: &Path, n: usize, nx: usize, ny: usize) -> (PathBuf, PathBuf) {
    let all = terrain(n, 7);
    let many = dir.join("many.pcimg");
    std::fs::create_dir(&many).unwrap();
    let opts = WriteOptions::default();
    for j in 0..ny {
        for i in 0..nx {
            let c = cell(&all, nx, ny, i, j);
            write_part(&many.join(format!("tile-{i}-{j}.tif")), &c, &opts).unwrap();
        }
    }
    let r = build_index(&many, &IndexOptions::default(), &|_| {}).unwrap();
    assert_eq!(r.parts, nx * ny);
    assert!(r.nodes >= 1 && r.no_overview.is_none(), "{r:?}");
    let one = dir.join("one.tif");
    write_part(&one, &all, &opts).unwrap();
    (many, one)
}

/// The part of `ds` whose file is `path`.
fn the_part<'a>(ds: &'a Dataset, path: &Path) -> &'a pcimg::store::Part {
    ds.parts()
        .unwrap()
        .into_iter()
        .find(|p| p.path == path)
        .unwrap()
}

fn exe() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
    c.env("NODEVICE_SELECT", "1");
    c
}

/// `pcimg render` from straight above at `w` × `h`: the frame's filled mask and
/// the report line.
fn top_frame(ds: &Path, out: &Path, budget: u64, w: u32, h: u32) -> (Vec<bool>, String) {
    let o = exe()
        .arg("render")
        .arg(ds)
        .arg("-o")
        .arg(out)
        .args([
            "--view",
            "0,-89.9",
            "--renderer",
            "cpu",
            "--color",
            "height",
        ])
        .args(["--width", &w.to_string(), "--height", &h.to_string()])
        .args(["--budget", &budget.to_string()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    let img = image::open(out).unwrap().to_rgba8();
    let mask = img.pixels().map(|p| p[0] | p[1] | p[2] != 0).collect();
    (mask, err)
}

/// The number at the start of the report line: points drawn.
fn points_drawn(report: &str) -> u64 {
    let line = report
        .lines()
        .find(|l| l.contains(" points from "))
        .unwrap();
    line.split(' ')
        .next()
        .unwrap()
        .replace(',', "")
        .parse()
        .unwrap()
}

#[test]
fn top_view_of_many_parts_covers_what_one_part_covers() {
    let dir = tempfile::tempdir().unwrap();
    let (many, one) = datasets(dir.path(), 400_000, 6, 4);
    let ds = Dataset::open(&many).unwrap();
    assert!(ds.index_bytes.is_some() && ds.has_overview());
    assert!(
        ds.parts().unwrap().into_iter().all(|p| !p.is_open()),
        "opening read a part"
    );
    // The parts' coarsest tiles alone hold more than the budget.
    let tops: u64 = ds
        .parts()
        .unwrap()
        .into_iter()
        .map(|p| p.levels.last().unwrap().points.unwrap())
        .sum();
    let budget = 60_000;
    assert!(tops > 2 * budget, "tops {tops}");
    let (w, h) = (60, 40);
    let (m_many, r_many) = top_frame(&many, &dir.path().join("m.png"), budget, w, h);
    let (m_one, r_one) = top_frame(&one, &dir.path().join("o.png"), budget, w, h);
    assert!(!r_many.contains("gave up"), "{r_many}");
    assert!(points_drawn(&r_many) <= budget, "{r_many}");
    assert!(points_drawn(&r_one) <= budget, "{r_one}");
    let filled = |m: &[bool]| m.iter().filter(|&&f| f).count();
    let both = m_one
        .iter()
        .zip(&m_many)
        .filter(|(a, b)| **a && **b)
        .count();
    let (n_one, n_many) = (filled(&m_one), filled(&m_many));
    assert!(n_one > (w * h / 6) as usize, "one part fills {n_one}");
    // The same pixels, within a few at the edges of the sampling.
    assert!(
        both as f64 >= 0.97 * n_one as f64 && both as f64 >= 0.97 * n_many as f64,
        "one part fills {n_one}, many parts {n_many}, both {both}\n{r_one}\n{r_many}"
    );
    // Without the index (as an older pcimg wrote it) the same budget leaves holes:
    // each part's coarsest tile competes for it.
    std::fs::remove_file(many.join("pcimg-index.json")).unwrap();
    std::fs::remove_dir_all(many.join("overview")).unwrap();
    let (m_old, r_old) = top_frame(&many, &dir.path().join("x.png"), budget, w, h);
    assert!(r_old.contains("gave up"), "{r_old}");
    assert!(r_old.contains("pcimg index"), "no hint: {r_old}");
    assert!(filled(&m_old) < n_one * 9 / 10, "{r_old}");
}

#[test]
fn the_index_notices_removed_replaced_and_unlisted_parts() {
    let dir = tempfile::tempdir().unwrap();
    let (many, _) = datasets(dir.path(), 60_000, 3, 2);
    // The store's error names the file and carries the remedy (rebuild this
    // dataset's index); the binary's advice names the command.
    let reindex = Some(pcimg::store::Remedy::Reindex {
        dataset: many.clone(),
    });
    let advised = |e: pcimg::store::StoreError| {
        assert_eq!(e.remedy.as_deref(), reindex.as_ref(), "{e}");
        pcimg::advice::store(&e)
    };
    let open_err = || advised(Dataset::open(&many).unwrap_err());
    Dataset::open(&many).unwrap();
    let part = many.join("tile-1-1.tif");
    let keep = std::fs::read(&part).unwrap();

    // Removed.
    std::fs::remove_file(&part).unwrap();
    let e = open_err();
    assert!(
        e.contains("tile-1-1.tif") && e.contains("pcimg index") && e.contains("missing"),
        "{e}"
    );

    // Replaced by other points: opening reads no part (a thousand parts open in
    // milliseconds), so the change is named when the part is first read.
    let read_err = || {
        let ds = Dataset::open(&many).unwrap();
        advised(the_part(&ds, &part).read_level(0, &[0]).unwrap_err())
    };
    let other = cell(&terrain(20_000, 99), 3, 2, 1, 1);
    write_part(&part, &other, &WriteOptions::default()).unwrap();
    let e = read_err();
    assert!(
        e.contains("tile-1-1.tif") && e.contains("changed") && e.contains("pcimg index"),
        "{e}"
    );

    // The same bytes, written again: the modification time tells.
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(&part, &keep).unwrap();
    let e = read_err();
    assert!(e.contains("changed") && e.contains("modified since"), "{e}");

    // Re-indexed, it opens; a part added after is named.
    build_index(&many, &IndexOptions::default(), &|_| {}).unwrap();
    Dataset::open(&many).unwrap();
    std::fs::copy(&part, many.join("tile-9-9.tif")).unwrap();
    let e = open_err();
    assert!(
        e.contains("tile-9-9.tif") && e.contains("not in the dataset's index"),
        "{e}"
    );
    std::fs::remove_file(many.join("tile-9-9.tif")).unwrap();

    // A damaged index is named with the command that rebuilds it.
    std::fs::write(many.join("pcimg-index.json"), "{\"format\": ").unwrap();
    let e = open_err();
    assert!(
        e.contains("pcimg-index.json") && e.contains("pcimg index"),
        "{e}"
    );

    // An old dataset (no index) opens as before, with a hint.
    std::fs::remove_file(many.join("pcimg-index.json")).unwrap();
    let ds = Dataset::open(&many).unwrap();
    assert!(!ds.has_overview() && ds.part_count() == 6);
    assert!(ds.unindexed);
    assert!(
        pcimg::advice::dataset_note(&ds)
            .unwrap()
            .contains("pcimg index")
    );

    // A part damaged after the dataset was opened is named when first read.
    build_index(&many, &IndexOptions::default(), &|_| {}).unwrap();
    let ds = Dataset::open(&many).unwrap();
    std::fs::write(&part, b"II*\0 not a part any more").unwrap();
    let e = advised(the_part(&ds, &part).read_level(0, &[0]).unwrap_err());
    assert!(
        e.contains("tile-1-1.tif") && e.contains("pcimg index"),
        "{e}"
    );
}

#[test]
fn selection_keeps_the_budget_and_every_visible_part() {
    let dir = tempfile::tempdir().unwrap();
    let (many, _) = datasets(dir.path(), 300_000, 5, 5);
    let ds = Dataset::open(&many).unwrap();
    let root_points = ds.part(ds.root().unwrap()).unwrap().meta.point_count;
    let bounds = ds.bounds();
    let mut r = pcimg::synth::Rng::new(3);
    for case in 0..200 {
        let mut cam = Camera::fit(&bounds);
        let view = format!(
            "{:.1},{:.1},{:.1}",
            r.f64() * 360.0,
            -89.0 + r.f64() * 80.0,
            20.0 + r.f64() * 1500.0
        );
        cam.apply_view(&camera::parse_view(&view).unwrap());
        cam.set_clip_from_bounds(&bounds);
        let budget = root_points + (r.f64() * 400_000.0) as u64;
        let (w, h) = (320, 200);
        let sel = lod::select(&ds, &cam, w, h, LodMode::View { budget }, u64::MAX);
        assert!(
            sel.points <= budget,
            "case {case} {view}: {} > {budget}",
            sel.points
        );
        assert_eq!(sel.dropped_tiles, 0, "case {case} {view}");
        // Every part in view is drawn, itself or through a node above it.
        let frustum = cam.frustum(w as f64 / h as f64);
        let drawn: std::collections::HashSet<usize> = sel.tiles.iter().map(|t| t.part).collect();
        for (i, p) in ds.parts().unwrap().into_iter().enumerate() {
            let visible = p.levels[0]
                .tiles
                .iter()
                .any(|t| frustum.contains_aabb(&t.bounds) != Containment::Outside);
            if !visible {
                continue;
            }
            let mut up = Some(i);
            let mut covered = false;
            while let Some(k) = up {
                covered |= drawn.contains(&k);
                up = ds.parent(k);
            }
            assert!(
                covered,
                "case {case} {view}: part {i} in view but not drawn"
            );
        }
    }
    // The paper's distance rule and fixed levels reach the overview's layers.
    let levels = lod::level_count(&ds);
    let own = ds
        .parts()
        .unwrap()
        .into_iter()
        .map(|p| p.levels.len())
        .max()
        .unwrap();
    assert_eq!(levels, own + ds.layer_count() as usize);
    let cam = Camera::fit(&bounds);
    let top = lod::select(&ds, &cam, 320, 200, LodMode::Fixed(levels - 1), u64::MAX);
    assert_eq!(top.overview_tiles, top.tiles.len());
    assert_eq!(top.points, root_points);
    let finest = lod::select(&ds, &cam, 320, 200, LodMode::Fixed(0), u64::MAX);
    assert_eq!(finest.overview_tiles, 0);
    assert_eq!(finest.points, ds.points());
}

#[test]
fn info_and_index_commands_show_the_overview() {
    let dir = tempfile::tempdir().unwrap();
    let (many, _) = datasets(dir.path(), 60_000, 3, 2);
    let o = exe().arg("index").arg(&many).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("indexed 6 part(s)") && out.contains("overview of"),
        "{out}"
    );
    let o = exe().arg("info").arg(&many).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("index    pcimg-index.json"), "{out}");
    assert!(out.contains("layer(s) above the parts"), "{out}");
    let o = exe().args(["info", "--json"]).arg(&many).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["index_bytes"].as_u64().unwrap() > 0);
    assert!(!v["overview"].as_array().unwrap().is_empty());
    // A single file needs no index.
    let o = exe()
        .arg("index")
        .arg(many.join("tile-0-0.tif"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a directory"));
}

/// `pcimg index --memory`: a budget below what the parts' count needs is
/// refused before anything changes (the index in place, no file left); one that
/// allows a single node at a time builds the same index as an unbounded one.
#[test]
fn index_keeps_to_its_memory_budget_or_refuses_it() {
    let dir = tempfile::tempdir().unwrap();
    let (many, _) = datasets(dir.path(), 60_000, 3, 2);
    let root = |ds: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(ds.join("pcimg-index.json")).unwrap()).unwrap()
    };
    let before = std::fs::read(many.join("pcimg-index.json")).unwrap();
    let listing = |ds: &Path| {
        let mut n: Vec<String> = std::fs::read_dir(ds)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        n.sort();
        n
    };
    let names = listing(&many);
    let o = exe()
        .args(["index", "--memory", "1KiB"])
        .arg(&many)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("indexing 6 parts needs about") && err.contains("--memory"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(many.join("pcimg-index.json")).unwrap(),
        before
    );
    assert_eq!(listing(&many), names);
    // 6 parts of x, y, z and intensity: a node of at most 15,000 points needs
    // under 2 MiB, so 2 MiB builds one node at a time.
    let o = exe()
        .args(["index", "--memory", "2MiB"])
        .arg(&many)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let small = root(&many);
    let o = exe().arg("index").arg(&many).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let free = root(&many);
    for k in ["totals", "layers", "pages", "stride", "listing"] {
        assert_eq!(small[k], free[k], "{k}");
    }
    assert!(small["totals"]["nodes"].as_u64().unwrap() >= 1);
    assert!(!listing(&many).iter().any(|n| n.contains("tmp")));
}

#[test]
fn a_paged_index_opens_from_its_root_and_reads_the_pages_views_reach() {
    use pcimg::store::dataset::index::{INDEX_FILE, IndexFile, entry_of};
    let dir = tempfile::tempdir().unwrap();
    let ds_dir = common::grid_dataset(dir.path(), 40, 40, 30);
    let root_bytes = std::fs::metadata(ds_dir.join(INDEX_FILE)).unwrap().len();
    assert!(root_bytes <= 256 << 10, "root {root_bytes} bytes");

    // Opened from the root alone: totals, layers, the first page.
    let ds = Dataset::open(&ds_dir).unwrap();
    let (pages, loaded) = ds.index_pages();
    assert!(pages > 4 && loaded == 1, "{pages} pages, {loaded} loaded");
    assert_eq!(ds.part_count(), 1600);
    assert_eq!(ds.points(), 1600 * 30);
    assert!(ds.has_overview() && ds.layer_count() >= 2);

    // A view of one corner reads the pages of that corner.
    let b = ds.bounds();
    let corner = Bounds {
        min: b.min,
        max: [b.min[0] + 40.0, b.min[1] + 40.0, b.max[2]],
    };
    let mut cam = Camera::fit(&corner);
    cam.apply_view(&camera::parse_view("0,-89").unwrap());
    cam.set_clip_from_bounds(&b);
    let view = LodMode::View { budget: 50_000 };
    let near = lod::select(&ds, &cam, 320, 200, view, u64::MAX);
    let (_, after) = ds.index_pages();
    assert!(after < pages / 2, "{after} of {pages} pages for one corner");
    assert!(near.tiles.iter().any(|t| !ds.is_overview(t.part)));

    // What lazily loaded pages give is what every page loaded gives.
    let all = Dataset::open(&ds_dir).unwrap();
    assert_eq!(all.part_ids().unwrap().len(), 1600);
    assert_eq!(all.index_pages(), (pages, pages));
    let again = lod::select(&all, &cam, 320, 200, view, u64::MAX);
    let key = |s: &lod::Selection| {
        let mut v: Vec<_> = s.tiles.iter().map(|t| (t.part, t.level, t.tile)).collect();
        v.sort();
        v
    };
    assert_eq!(key(&near), key(&again));
    let whole = Camera::fit(&b);
    assert_eq!(
        lod::select(&ds, &whole, 320, 200, LodMode::Fixed(0), u64::MAX).points,
        ds.points()
    );

    // A box reaches the parts under it through the overview's covers.
    let ids = ds.parts_where(&|x: &Bounds| x.intersects(&corner)).unwrap();
    assert!(!ids.is_empty() && ids.len() < 50, "{} parts", ids.len());

    // `info` sums the dataset up from the root; `--parts` lists every part.
    let o = exe().arg("info").arg(&ds_dir).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("1600 part(s)") && out.contains("more pages"),
        "{out}"
    );
    assert!(!out.contains("part 1/1600"), "{out}");
    let o = exe()
        .args(["info", "--parts"])
        .arg(&ds_dir)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("part 1600/1600"),
        "{}",
        &out[..out.len().min(400)]
    );

    // A damaged page is named, with the command that rebuilds the index,
    // when a view reaches it; nothing panics.
    let page = std::fs::read_dir(ds_dir.join("pages-0"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .max()
        .unwrap();
    std::fs::write(&page, "{\"parts\": [").unwrap();
    let ds = Dataset::open(&ds_dir).unwrap();
    let e = ds.part_ids().unwrap_err();
    assert_eq!(
        e.remedy.as_deref(),
        Some(&pcimg::store::Remedy::Reindex {
            dataset: ds_dir.clone()
        })
    );
    let advice = pcimg::advice::store(&e);
    assert!(
        advice.contains(&*page.file_name().unwrap().to_string_lossy())
            && advice.contains("pcimg index"),
        "{advice}"
    );
    let _ = lod::select(&ds, &Camera::fit(&b), 320, 200, view, u64::MAX);
    let _ = lod::select(&ds, &Camera::fit(&b), 320, 200, LodMode::Fixed(0), u64::MAX);

    // An index of version 1 still opens; `pcimg index` upgrades it in place.
    let mut files: Vec<PathBuf> = std::fs::read_dir(&ds_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .collect();
    files.sort();
    let entries = files
        .iter()
        .take(3)
        .map(|f| {
            let p = pcimg::store::Part::open(f).unwrap();
            entry_of(&p, &f.file_name().unwrap().to_string_lossy()).unwrap()
        })
        .collect();
    let small = dir.path().join("v1.pcimg");
    std::fs::create_dir(&small).unwrap();
    for f in files.iter().take(3) {
        std::fs::copy(f, small.join(f.file_name().unwrap())).unwrap();
    }
    IndexFile::new(entries, Vec::new()).save(&small).unwrap();
    let v1 = std::fs::read_to_string(small.join(INDEX_FILE)).unwrap();
    assert!(v1.contains("\"version\":1"), "{v1}");
    let ds = Dataset::open(&small).unwrap();
    assert_eq!(ds.part_count(), 3);
    let o = exe().arg("index").arg(&small).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v2 = std::fs::read_to_string(small.join(INDEX_FILE)).unwrap();
    assert!(v2.contains("\"version\":2"), "{}", &v2[..200]);
    let ds = Dataset::open(&small).unwrap();
    assert!(ds.has_overview() && ds.part_count() == 3);
}
