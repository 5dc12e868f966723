//! Level selection: the paper's distance rule at its thresholds, the point budget,
//! frustum culling by stored tile bounds, the memory budget, and the loader.

use pcimg::camera::{Camera, Containment};
use pcimg::lod::{self, LodMode, TileCache};
use pcimg::store::{Dataset, WriteOptions, write_part};
use std::sync::Arc;

/// A dataset of 3 spatial parts of the synthetic scene (about 1.3 M points).
fn dataset(dir: &std::path::Path) -> Arc<Dataset> {
    let pts = pcimg::synth::scene(1_300_000, 4);
    // Split by x into three parts, as the converter's spatial partition would.
    let xs = pts.bounds();
    let w = (xs.max[0] - xs.min[0]) / 3.0;
    for k in 0..3 {
        let lo = xs.min[0] + w * k as f64;
        let mut part = pts.empty_like();
        for i in 0..pts.len() {
            let inside = pts.x[i] >= lo && (pts.x[i] < lo + w || k == 2);
            if inside {
                part.x.push(pts.x[i]);
                part.y.push(pts.y[i]);
                part.z.push(pts.z[i]);
                part.attributes[0].values.push(pts.attributes[0].values[i]);
            }
        }
        write_part(
            &dir.join(format!("p{k}.tif")),
            &part,
            &WriteOptions::default(),
        )
        .unwrap();
    }
    Arc::new(Dataset::open(dir).unwrap())
}

#[test]
fn distance_rule_switches_at_the_thresholds() {
    let diag = 100.0;
    for k in 0..5 {
        let t = 0.5 * diag * 2f64.powi(k);
        assert_eq!(lod::distance_level(t * 0.999, diag, 6), k as usize);
        assert_eq!(lod::distance_level(t * 1.001, diag, 6), k as usize + 1);
    }
    assert_eq!(
        lod::distance_level(1e9, diag, 4),
        3,
        "clamped to the coarsest level"
    );
    assert_eq!(lod::distance_level(0.0, diag, 4), 0);
}

#[test]
fn distance_mode_picks_one_level_per_part_from_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let b = ds.bounds();
    let diag = b.extent().iter().map(|e| e * e).sum::<f64>().sqrt();
    let mut cam = Camera::fit(&b);
    let mut seen = Vec::new();
    for dist in [0.3 * diag, 0.7 * diag, 1.5 * diag] {
        cam.distance = dist;
        cam.set_clip_from_bounds(&b);
        let d = cam.distance_to(b.center());
        let sel = lod::select(&ds, &cam, 640, 480, LodMode::Distance, u64::MAX);
        assert!(!sel.tiles.is_empty());
        for t in &sel.tiles {
            let levels = ds.part(t.part).unwrap().levels.len();
            assert_eq!(
                t.level,
                lod::distance_level(d, diag, levels),
                "distance {dist}"
            );
        }
        seen.push(sel.tiles[0].level);
    }
    assert_eq!(seen, [0, 1, 2], "closer means finer");
}

#[test]
fn view_mode_never_exceeds_the_budget_and_refines_near_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let b = ds.bounds();
    for budget in [50_000u64, 200_000, 600_000, 5_000_000] {
        for (yaw, pitch, zoom) in [(0.0, -30.0, 1.0), (90.0, -60.0, 0.3), (200.0, -10.0, 0.1)] {
            let mut cam = Camera::fit(&b);
            cam.apply_view(&pcimg::camera::parse_view(&format!("{yaw},{pitch}")).unwrap());
            cam.zoom(zoom);
            cam.set_clip_from_bounds(&b);
            let sel = lod::select(&ds, &cam, 800, 600, LodMode::View { budget }, u64::MAX);
            assert!(
                sel.points <= budget,
                "budget {budget}: {} points",
                sel.points
            );
            let sum: u64 = sel.tiles.iter().map(|t| t.points).sum();
            assert_eq!(sum, sel.points);
        }
    }
    // A large budget close up reaches level 0 somewhere.
    let mut cam = Camera::fit(&b);
    cam.zoom(0.05);
    cam.set_clip_from_bounds(&b);
    let sel = lod::select(
        &ds,
        &cam,
        1280,
        720,
        LodMode::View { budget: 5_000_000 },
        u64::MAX,
    );
    assert_eq!(sel.levels.map(|l| l.0), Some(0));
    // A budget below the coarsest tile still draws one tile (the nearest), not
    // an empty frame.
    let cam = Camera::fit(&b);
    let sel = lod::select(&ds, &cam, 800, 600, LodMode::View { budget: 1 }, u64::MAX);
    assert_eq!(sel.tiles.len(), 1, "{:?}", sel.levels);
    assert_eq!(sel.points, sel.tiles[0].points);
}

/// A small view (a terminal pane in text mode) zoomed onto the centre, where
/// tiles' children meet, still refines past the coarsest tiles: the automatic
/// budget holds what one refinement adds (four tiles).
#[test]
fn a_small_view_zoomed_in_refines_past_the_coarsest_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let b = ds.bounds();
    let budget = lod::budget_for_pixels(160, 90, lod::DEFAULT_BUDGET_CAP);
    let coarsest = (0..3)
        .filter_map(|p| ds.part(p))
        .map(|p| p.levels.len() - 1)
        .min()
        .unwrap();
    let mut cam = Camera::fit(&b);
    cam.zoom(0.02);
    cam.set_clip_from_bounds(&b);
    let sel = lod::select(&ds, &cam, 160, 90, LodMode::View { budget }, u64::MAX);
    let finest = sel.levels.map(|l| l.0).unwrap();
    assert!(
        finest < coarsest,
        "level {finest} (coarsest {coarsest}), {} points, budget {budget}",
        sel.points
    );
    assert!(sel.points <= budget);
}

#[test]
fn tiles_outside_the_frustum_are_never_selected_or_loaded() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let b = ds.bounds();
    let mut cam = Camera::fit(&b);
    // Close to one corner: most tiles are out of view.
    cam.zoom(0.08);
    cam.target = glam::DVec3::new(b.min[0] + 20.0, b.min[1] + 20.0, b.min[2]);
    cam.set_clip_from_bounds(&b);
    let frustum = cam.frustum(800.0 / 600.0);
    for mode in [
        LodMode::View { budget: 2_000_000 },
        LodMode::Fixed(0),
        LodMode::Distance,
    ] {
        let sel = lod::select(&ds, &cam, 800, 600, mode, u64::MAX);
        assert!(sel.culled > 0, "{mode:?} culled nothing");
        for t in &sel.tiles {
            assert_ne!(frustum.contains_aabb(&t.bounds), Containment::Outside);
        }
        // The loader loads exactly the selection.
        let cache = TileCache::new(ds.clone(), u64::MAX, 2);
        let tiles = cache.load_all(&sel.tiles).unwrap();
        assert_eq!(tiles.len(), sel.tiles.len());
        assert_eq!(
            tiles.iter().map(|t| t.len() as u64).sum::<u64>(),
            sel.points
        );
        assert_eq!(cache.stats().loads as usize, sel.tiles.len());
    }
}

#[test]
fn memory_budget_gives_up_far_tiles_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let cam = Camera::fit(&ds.bounds());
    let full = lod::select(&ds, &cam, 800, 600, LodMode::Fixed(0), u64::MAX);
    let memory = full.points * lod::select::BYTES_PER_LOADED_POINT / 3;
    let sel = lod::select(&ds, &cam, 800, 600, LodMode::Fixed(0), memory);
    assert!(sel.dropped_tiles > 0);
    assert_eq!(sel.points + sel.dropped_points, full.points);
    assert!(sel.points * lod::select::BYTES_PER_LOADED_POINT <= memory);
}

#[test]
fn background_loader_delivers_requested_tiles_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let cam = Camera::fit(&ds.bounds());
    let sel = lod::select(
        &ds,
        &cam,
        800,
        600,
        LodMode::View { budget: 400_000 },
        u64::MAX,
    );
    let cache = TileCache::new(ds.clone(), 1 << 30, 2);
    cache.request(&sel.tiles);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while !cache.has_all(&sel.tiles) {
        assert!(std::time::Instant::now() < deadline, "tiles never arrived");
        let _ = cache
            .arrivals
            .recv_timeout(std::time::Duration::from_millis(100));
    }
    assert_eq!(cache.ready(&sel.tiles).len(), sel.tiles.len());
    assert!(cache.take_errors().is_empty());
    // A tiny budget evicts tiles that are no longer wanted.
    let small = TileCache::new(ds.clone(), 1, 1);
    small.request(&sel.tiles[..1]);
    while !small.has_all(&sel.tiles[..1]) {
        let _ = small
            .arrivals
            .recv_timeout(std::time::Duration::from_millis(100));
    }
    small.request(&sel.tiles[1..2]);
    while !small.has_all(&sel.tiles[1..2]) {
        let _ = small
            .arrivals
            .recv_timeout(std::time::Duration::from_millis(100));
    }
    assert_eq!(small.stats().tiles, 1, "the unwanted tile was evicted");
}

#[test]
fn unreadable_tiles_are_not_retried_and_coarser_tiles_stand_in() {
    use pcimg::store::Compression;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("z.tif");
    let opts = WriteOptions {
        compression: Compression::Deflate,
        ..Default::default()
    };
    write_part(&path, &pcimg::synth::scene(400_000, 3), &opts).unwrap();
    // Corrupt the first band of every level-0 tile.
    let mut bytes = std::fs::read(&path).unwrap();
    let t = pcimg::store::tiff::ifd::Tiff::parse(&bytes).unwrap();
    let offsets = t.uints(&bytes, &t.ifds[0], 324).unwrap().unwrap();
    let counts = t.uints(&bytes, &t.ifds[0], 325).unwrap().unwrap();
    let first_band = offsets.len() / 4;
    for (&o, &n) in offsets.iter().zip(&counts).take(first_band) {
        for b in &mut bytes[o as usize..(o + n.min(16)) as usize] {
            *b ^= 0x5a;
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let ds = Arc::new(Dataset::open(&path).unwrap());
    assert!(ds.parts().unwrap()[0].levels.len() >= 3);
    let cam = Camera::fit(&ds.bounds());
    let pick = |level| lod::select(&ds, &cam, 800, 600, LodMode::Fixed(level), u64::MAX).tiles;
    let (fine, coarse) = (pick(0), pick(1));
    assert!(fine.len() > coarse.len() && !coarse.is_empty());
    let cache = TileCache::new(ds.clone(), 1 << 30, 2);
    // Tiles loaded at once are kept in the cache too.
    cache.load_all(&coarse).unwrap();
    assert!(cache.has_all(&coarse));
    assert!(cache.stand_ins(&coarse).is_empty(), "nothing is missing");
    // Every level-0 tile fails, once, and says so on the arrivals channel (a
    // view waiting for it redraws); the level-1 tiles stand in for them.
    cache.request(&fine);
    let mut news = 0;
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while cache.unreadable(&fine) < fine.len() || news < fine.len() {
        assert!(std::time::Instant::now() < deadline, "timed out");
        if cache
            .arrivals
            .recv_timeout(std::time::Duration::from_millis(20))
            .is_ok()
        {
            news += 1;
        }
    }
    let errors = cache.take_errors();
    assert_eq!(errors.len(), fine.len(), "{errors:?}");
    assert!(errors[0].to_string().contains("z.tif"), "{}", errors[0]);
    let mut stand: Vec<_> = cache.stand_ins(&fine).iter().map(|t| t.key).collect();
    let mut want: Vec<_> = coarse.iter().map(lod::TileKey::from).collect();
    stand.sort();
    want.sort();
    assert_eq!(stand, want);
    // Bad bytes would be bad again: unlike a request the server did not answer
    // (tried again after a growing wait: tests/retry.rs), they wait for no retry.
    assert_eq!(cache.retrying(&fine), 0);
    assert_eq!(cache.retries().tiles, 0, "{}", cache.retries());
    // Asked for again, none is queued (a queued tile counts as pending at once,
    // before any worker takes it), so no error can come back.
    cache.request(&fine);
    assert_eq!(
        cache.stats().pending,
        0,
        "unreadable tiles were asked for again"
    );
    assert!(cache.take_errors().is_empty());
}
