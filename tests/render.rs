//! Renderer integration tests: CPU and wgpu agree on a synthetic scene, depth
//! test, splat sizes, clipping, empty input, caching and chunking.
//!
//! The wgpu tests need an adapter (lavapipe here). With `CI=true` a missing
//! adapter fails the test; elsewhere the test prints a note and passes.

use std::sync::{Mutex, OnceLock};

use pcimg::points::Bounds;
use pcimg::render::color::pack_rgb;
use pcimg::render::cpu::{CpuRasterizer, CpuStrategy};
use pcimg::render::gpu::{GpuOptions, GpuRasterizer};
use pcimg::render::{
    Camera, CameraMode, Frame, PointBatch, Rasterizer, RenderError, RenderOptions, RendererChoice,
    create,
};

const BG: [u8; 3] = [10, 20, 30];

fn opts(w: u32, h: u32, size: u32) -> RenderOptions {
    RenderOptions {
        width: w,
        height: h,
        point_size: size,
        eye_dome_lighting: false,
        edl: Default::default(),
        background: BG,
    }
}

/// Owned columns for one batch.
struct Cols {
    origin: [f64; 3],
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    c: Vec<u32>,
}

impl Cols {
    fn new(origin: [f64; 3]) -> Cols {
        Cols {
            origin,
            x: vec![],
            y: vec![],
            z: vec![],
            c: vec![],
        }
    }
    fn push(&mut self, p: [f64; 3], c: u32) {
        self.x.push((p[0] - self.origin[0]) as f32);
        self.y.push((p[1] - self.origin[1]) as f32);
        self.z.push((p[2] - self.origin[2]) as f32);
        self.c.push(c);
    }
    fn batch(&self) -> PointBatch<'_> {
        PointBatch {
            origin: self.origin,
            x: &self.x,
            y: &self.y,
            z: &self.z,
            color: &self.c,
        }
    }
}

/// Deterministic xorshift in [0, 1).
struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// ~200k points: a ground plane, a sphere, a box shell and a tilted disc at
/// different depths, in two batches with different (georeferenced) origins.
fn scene() -> (Vec<Cols>, Bounds) {
    let base = [637_000.0, 5_100_000.0, 300.0];
    let mut a = Cols::new(base);
    let mut b = Cols::new([base[0] + 40.0, base[1] + 25.0, base[2] + 5.0]);
    let mut r = Rng(0x9e37_79b9_7f4a_7c15);
    for _ in 0..80_000 {
        let (x, y) = (r.f() * 100.0, r.f() * 100.0);
        let z = 2.0 * (x * 0.05).sin() * (y * 0.07).cos();
        let shade = (100.0 + 20.0 * z) as u8;
        a.push(
            [base[0] + x, base[1] + y, base[2] + z],
            pack_rgb(shade, 160, 60),
        );
    }
    for _ in 0..50_000 {
        let (u, v) = (r.f() * 2.0 - 1.0, r.f() * std::f64::consts::TAU);
        let s = (1.0 - u * u).sqrt();
        let p = [
            30.0 + 12.0 * s * v.cos(),
            60.0 + 12.0 * s * v.sin(),
            14.0 + 12.0 * u,
        ];
        a.push(
            [base[0] + p[0], base[1] + p[1], base[2] + p[2]],
            pack_rgb(220, 40, 40),
        );
    }
    for _ in 0..50_000 {
        let face = (r.f() * 6.0) as usize;
        let (s, t) = (r.f() * 20.0, r.f() * 20.0);
        let p = match face {
            0 => [0.0, s, t],
            1 => [20.0, s, t],
            2 => [s, 0.0, t],
            3 => [s, 20.0, t],
            4 => [s, t, 0.0],
            _ => [s, t, 20.0],
        };
        b.push(
            [
                base[0] + 60.0 + p[0],
                base[1] + 20.0 + p[1],
                base[2] + 2.0 + p[2],
            ],
            pack_rgb(40, 90, 230),
        );
    }
    for _ in 0..20_000 {
        let (rad, ang) = (r.f().sqrt() * 15.0, r.f() * std::f64::consts::TAU);
        let (x, y) = (rad * ang.cos(), rad * ang.sin());
        b.push(
            [
                base[0] + 75.0 + x,
                base[1] + 75.0 + y,
                base[2] + 20.0 + 0.5 * x,
            ],
            pack_rgb(240, 220, 50),
        );
    }
    let bounds = Bounds {
        min: [base[0], base[1], base[2] - 3.0],
        max: [base[0] + 100.0, base[1] + 100.0, base[2] + 30.0],
    };
    (vec![a, b], bounds)
}

/// Saves `f` as PNG under `$PCIMG_TEST_PNG_DIR` when that is set (for eyeballing).
fn dump(f: &Frame, name: &str) {
    if let Some(dir) = std::env::var_os("PCIMG_TEST_PNG_DIR") {
        let p = std::path::Path::new(&dir).join(format!("{name}.png"));
        f.save_png(&p).unwrap();
    }
}

fn batches(cols: &[Cols]) -> Vec<PointBatch<'_>> {
    cols.iter().map(Cols::batch).collect()
}

fn is_bg(p: &[u8]) -> bool {
    p[..3] == BG
}

fn count_drawn(f: &Frame) -> usize {
    f.rgba.chunks_exact(4).filter(|p| !is_bg(p)).count()
}

/// Fraction of identical pixels among those either frame drew (the scene
/// covers a small part of the frame: counting the empty background as agreement
/// would hide a renderer that drew a tenth of the scene wrong).
fn agreement(a: &Frame, b: &Frame) -> f64 {
    agreement_tol(a, b, 0)
}

/// Fraction of pixels within `tol` per channel, among those either frame drew.
fn agreement_tol(a: &Frame, b: &Frame, tol: u8) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let (mut drawn, mut same) = (0usize, 0usize);
    for (p, q) in a.rgba.chunks_exact(4).zip(b.rgba.chunks_exact(4)) {
        if is_bg(p) && is_bg(q) {
            continue;
        }
        drawn += 1;
        if p.iter().zip(q.iter()).all(|(x, y)| x.abs_diff(*y) <= tol) {
            same += 1;
        }
    }
    assert!(drawn > 0, "neither frame drew anything");
    same as f64 / drawn as f64
}

/// One shared GPU rasterizer per process (device creation is slow on lavapipe).
fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

/// A wgpu rasterizer with `o`; `None` (and a note) where no adapter exists,
/// a failure with `CI=true`.
fn gpu_or_skip(o: GpuOptions) -> Option<GpuRasterizer> {
    match GpuRasterizer::with_options(o) {
        Ok(g) => Some(g),
        Err(e) => {
            assert!(
                !in_ci(),
                "CI=true but no wgpu adapter could be created: {e}"
            );
            eprintln!("note: skipping wgpu test, no adapter: {e}");
            None
        }
    }
}

fn with_gpu(f: impl FnOnce(&mut GpuRasterizer)) {
    static GPU: OnceLock<Mutex<Option<GpuRasterizer>>> = OnceLock::new();
    let cell = GPU.get_or_init(|| Mutex::new(gpu_or_skip(GpuOptions::default())));
    let mut guard = cell.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(g) = guard.as_mut() {
        f(g);
    }
}

fn cpu_both() -> Vec<CpuRasterizer> {
    vec![
        CpuRasterizer::with_strategy(CpuStrategy::PerThread),
        CpuRasterizer::with_strategy(CpuStrategy::SharedAtomic),
    ]
}

#[test]
fn cpu_strategies_agree_and_scene_is_visible() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let mut cam = Camera::fit(&bounds);
    cam.aspect = 320.0 / 240.0;
    cam.fit_to(&bounds);
    for size in 1..=3 {
        let o = opts(320, 240, size);
        let mut r = cpu_both();
        let a = r[0].render(&cam, &bs, &o).unwrap();
        let b = r[1].render(&cam, &bs, &o).unwrap();
        assert_eq!(a.rgba, b.rgba, "strategies differ at size {size}");
        assert_eq!(a.stats.points_drawn, 200_000);
        let drawn = count_drawn(&a);
        assert!(drawn > 320 * 240 / 10, "scene covers too little: {drawn}");
        dump(&a, &format!("cpu_size{size}"));
        // Re-rendering reuses the buffers and gives the same image.
        let again = r[0].render(&cam, &bs, &o).unwrap();
        assert_eq!(a.rgba, again.rgba);
    }
}

#[test]
fn origin_split_does_not_change_the_image() {
    let (cols, bounds) = scene();
    let cam = Camera::fit(&bounds);
    let o = opts(320, 240, 1);
    let mut cpu = CpuRasterizer::new();
    let a = cpu.render(&cam, &batches(&cols), &o).unwrap();
    // The same points re-expressed relative to one other origin.
    let mut merged = Cols::new([637_050.0, 5_100_050.0, 310.0]);
    for c in &cols {
        for i in 0..c.x.len() {
            let p = [
                c.origin[0] + c.x[i] as f64,
                c.origin[1] + c.y[i] as f64,
                c.origin[2] + c.z[i] as f64,
            ];
            merged.push(p, c.c[i]);
        }
    }
    let b = cpu.render(&cam, &[merged.batch()], &o).unwrap();
    let agree = agreement(&a, &b);
    assert!(agree > 0.995, "agreement {agree}");
}

#[test]
fn cpu_and_gpu_agree() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let mut cam = Camera::fit(&bounds);
    cam.aspect = 320.0 / 240.0;
    cam.fit_to(&bounds);
    with_gpu(|gpu| {
        println!(
            "gpu: {} (64-bit atomics: {})",
            gpu.name(),
            gpu.has_int64_atomics()
        );
        for size in 1..=3 {
            let o = opts(320, 240, size);
            let c = CpuRasterizer::new().render(&cam, &bs, &o).unwrap();
            let g = gpu.render(&cam, &bs, &o).unwrap();
            dump(&g, &format!("gpu_size{size}"));
            if gpu.has_int64_atomics() {
                let agree = agreement(&c, &g);
                println!("size {size}: {:.4}% of pixels identical", agree * 100.0);
                assert!(agree >= 0.99, "size {size}: only {agree} of pixels agree");
            } else {
                let agree = agreement_tol(&c, &g, 8);
                assert!(agree >= 0.97, "size {size}: only {agree} of pixels agree");
            }
            assert_eq!(g.stats.points_drawn, 200_000);
        }
        // Second frame of the same batches: served from the cache.
        let g = gpu.render(&cam, &bs, &opts(320, 240, 1)).unwrap();
        assert_eq!(g.stats.upload_ms, 0.0);
        // Small chunks (many dispatches) give the same image.
        let full = gpu.render(&cam, &bs, &opts(320, 240, 1)).unwrap();
        let keep = gpu.chunk_points();
        gpu.set_chunk_points(7_000);
        let chunked = gpu.render(&cam, &bs, &opts(320, 240, 1)).unwrap();
        gpu.set_chunk_points(keep);
        assert_eq!(full.rgba, chunked.rgba);
        // EDL runs on the GPU's depth too.
        let mut e = opts(320, 240, 1);
        e.eye_dome_lighting = true;
        let lit = gpu.render(&cam, &bs, &e).unwrap();
        dump(&lit, "gpu_edl");
        let lit_cpu = CpuRasterizer::new().render(&cam, &bs, &e).unwrap();
        assert_ne!(lit.rgba, full.rgba);
        if gpu.has_int64_atomics() {
            let agree = agreement_tol(&lit, &lit_cpu, 2);
            assert!(agree >= 0.98, "EDL agreement {agree}");
        }
    });
}

#[test]
fn gpu_32bit_fallback_agrees_roughly() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let mut have_gpu = false;
    with_gpu(|_| have_gpu = true);
    if !have_gpu {
        return;
    }
    let mut gpu = GpuRasterizer::with_options(GpuOptions {
        force_32bit_atomics: true,
        ..Default::default()
    })
    .unwrap();
    assert!(!gpu.has_int64_atomics());
    let cam = Camera::fit(&bounds);
    let o = opts(320, 180, 2);
    let c = CpuRasterizer::new().render(&cam, &bs, &o).unwrap();
    let g = gpu.render(&cam, &bs, &o).unwrap();
    let agree = agreement_tol(&c, &g, 8);
    println!(
        "32-bit fallback: {:.3}% of pixels within 8/255",
        agree * 100.0
    );
    // 16-bit log depth still separates points 0.1% apart at 90% of the far
    // plane (a 16-bit projection depth would tie them and pick by colour).
    let mut pts = Cols::new([0.0; 3]);
    pts.push([0.0, 900.0, 0.0], pack_rgb(255, 255, 255)); // near, larger colour
    pts.push([0.0, 901.0, 0.0], pack_rgb(0, 0, 8)); // far, smaller colour
    let deep = Camera {
        near: 0.1,
        far: 1000.0,
        ..axis_camera()
    };
    let f = gpu.render(&deep, &[pts.batch()], &opts(65, 49, 1)).unwrap();
    assert_eq!(f.pixel(32, 24), Some([255, 255, 255, 255]));
    assert!(
        agree >= 0.97,
        "32-bit fallback: only {agree} of pixels agree"
    );
}

#[test]
fn gpu_cache_keeps_recent_batches_within_budget() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let cam = Camera::fit(&bounds);
    let mut have_gpu = false;
    with_gpu(|_| have_gpu = true);
    if !have_gpu {
        return;
    }
    let mut gpu = GpuRasterizer::new().unwrap();
    let o = opts(160, 120, 1);
    let (a, b) = (&bs[..1], &bs[1..]);
    let first = gpu.render(&cam, a, &o).unwrap();
    assert!(first.stats.upload_ms > 0.0);
    gpu.render(&cam, b, &o).unwrap();
    // `a` was not drawn last frame but stays within the default budget.
    assert_eq!(gpu.render(&cam, a, &o).unwrap().stats.upload_ms, 0.0);
    assert_eq!(gpu.cached_bytes(), 200_000 * 16);
    gpu.set_cache_budget(0);
    gpu.render(&cam, b, &o).unwrap();
    assert_eq!(gpu.cached_bytes(), cols[1].x.len() as u64 * 16);
    assert!(gpu.render(&cam, a, &o).unwrap().stats.upload_ms > 0.0);
    // Same pointers, changed contents: the fingerprint forces a re-upload.
    let mut changed = Cols::new(cols[0].origin);
    changed.x = cols[0].x.clone();
    changed.y = cols[0].y.clone();
    changed.z = cols[0].z.clone();
    changed.c = cols[0].c.clone();
    let before = gpu.render(&cam, &[changed.batch()], &o).unwrap();
    for c in changed.c.iter_mut() {
        *c = pack_rgb(1, 2, 3);
    }
    let after = gpu.render(&cam, &[changed.batch()], &o).unwrap();
    assert!(after.stats.upload_ms > 0.0);
    assert_ne!(before.rgba, after.rgba);
    gpu.invalidate_cache();
    assert_eq!(gpu.cached_bytes(), 0);
}

#[test]
fn gpu_shader_variants_agree() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let cam = Camera::fit(&bounds);
    for size in [1, 2] {
        let o = opts(320, 180, size);
        let mut reference = None;
        with_gpu(|gpu| reference = Some(gpu.render(&cam, &bs, &o).unwrap()));
        let Some(reference) = reference else {
            return;
        };
        for (no_early_depth_test, points_per_thread, merge_runs, subgroups, segmented_runs) in [
            (true, 1, false, false, false),
            (false, 3, false, false, false),
            (true, 64, false, false, false),
            (false, 8, true, false, false),
            (true, 5, true, false, false),
            (false, 1, false, true, false),
            (false, 8, false, true, false),
            (true, 3, false, true, false),
            (false, 8, false, true, true),
            (true, 2, false, true, true),
        ] {
            let mut g = GpuRasterizer::with_options(GpuOptions {
                no_early_depth_test,
                points_per_thread,
                merge_runs: Some(merge_runs),
                subgroups: Some(subgroups),
                segmented_runs,
                ..Default::default()
            })
            .unwrap();
            if subgroups && in_ci() {
                assert!(g.has_subgroups(), "{}: no subgroups", g.name());
            }
            let f = g.render(&cam, &bs, &o).unwrap();
            assert_eq!(
                f.rgba, reference.rgba,
                "size {size}, no early {no_early_depth_test}, ppt {points_per_thread}, merge {merge_runs}, subgroups {subgroups}, segmented {segmented_runs}"
            );
        }
    }
}

/// Runs of 1 to 48 consecutive points on one spot (or straddling a few pixels),
/// with depths from a small set so that ties are common and broken by colour:
/// what the subgroup reduction sees in Morton order, where a subgroup's points
/// mostly share a pixel. Every variant must leave the image the plain
/// per-point atomics leave.
#[test]
fn gpu_subgroup_reduction_keeps_the_nearest_point_of_each_pixel() {
    let origin = [500_000.0, 4_000_000.0, 0.0];
    let mut cols = Cols::new(origin);
    let mut r = Rng(0x51ed_270b_2744_1f01);
    while cols.x.len() < 150_000 {
        let len = 1 + (r.f() * 48.0) as usize;
        let (x, y) = (r.f() * 60.0, r.f() * 40.0);
        let spread = if r.f() < 0.3 { 0.6 } else { 0.0 };
        for _ in 0..len {
            let z = (r.f() * 4.0).floor() * 0.5;
            let c = pack_rgb((r.f() * 255.0) as u8, (r.f() * 255.0) as u8, 7);
            let (dx, dy) = (r.f() * spread, r.f() * spread);
            cols.push([origin[0] + x + dx, origin[1] + y + dy, origin[2] + z], c);
        }
    }
    let bounds = Bounds {
        min: [origin[0], origin[1], 0.0],
        max: [origin[0] + 61.0, origin[1] + 41.0, 2.0],
    };
    let cam = Camera::fit(&bounds);
    let o = opts(96, 64, 1);
    let bs = [cols.batch()];
    let plain = |subgroups, segmented_runs, points_per_thread| {
        gpu_or_skip(GpuOptions {
            subgroups: Some(subgroups),
            segmented_runs,
            points_per_thread,
            ..Default::default()
        })
    };
    let Some(mut reference) = plain(false, false, 1) else {
        return;
    };
    if !reference.has_int64_atomics() {
        return;
    }
    let want = reference.render(&cam, &bs, &o).unwrap();
    let drawn = count_drawn(&want);
    assert!(
        drawn > 500 && drawn * 20 < cols.x.len(),
        "{drawn} pixels drawn: the scene should pile many points on each"
    );
    for (segmented, ppt) in [(false, 1), (false, 8), (true, 1), (true, 8), (true, 3)] {
        let mut g = plain(true, segmented, ppt).unwrap();
        if !g.has_subgroups() {
            assert!(!in_ci(), "{}: no subgroups", g.name());
            eprintln!("note: {}: no subgroups, nothing to compare", g.name());
            return;
        }
        let f = g.render(&cam, &bs, &o).unwrap();
        let differ = f
            .rgba
            .chunks(4)
            .zip(want.rgba.chunks(4))
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(differ, 0, "segmented {segmented}, ppt {ppt}: pixels differ");
    }
}

/// A camera at the world origin looking along +Y, and a frame whose centre
/// pixel (32, 24) is where points on the +Y axis land.
fn axis_camera() -> Camera {
    Camera {
        mode: CameraMode::Fly,
        position: glam::DVec3::ZERO,
        yaw: 90f64.to_radians(),
        pitch: 0.0,
        near: 0.1,
        far: 1000.0,
        ..Camera::default()
    }
}

fn all_renderers() -> Vec<Box<dyn Rasterizer>> {
    let mut v: Vec<Box<dyn Rasterizer>> = cpu_both()
        .into_iter()
        .map(|c| Box::new(c) as Box<dyn Rasterizer>)
        .collect();
    if let Ok(g) = GpuRasterizer::new() {
        v.push(Box::new(g));
    } else if in_ci() {
        panic!("CI=true but no wgpu adapter could be created");
    }
    v
}

fn render_points(r: &mut dyn Rasterizer, pts: &[([f64; 3], u32)], size: u32) -> Frame {
    let mut c = Cols::new([0.0; 3]);
    for &(p, col) in pts {
        c.push(p, col);
    }
    r.render(&axis_camera(), &[c.batch()], &opts(65, 49, size))
        .unwrap()
}

#[test]
fn nearest_point_wins_regardless_of_order() {
    let red = pack_rgb(255, 0, 0);
    let blue = pack_rgb(0, 0, 255);
    let near = ([0.0, 10.0, 0.0], red);
    let far = ([0.0, 50.0, 0.0], blue);
    for mut r in all_renderers() {
        for pts in [[near, far], [far, near]] {
            let f = render_points(r.as_mut(), &pts, 1);
            assert_eq!(f.pixel(32, 24), Some([255, 0, 0, 255]), "{}", r.name());
            assert_eq!(count_drawn(&f), 1);
        }
        // Equal depth: the smaller colour value wins, whatever the order.
        let f = render_points(r.as_mut(), &[([0.0, 10.0, 0.0], blue), near], 1);
        assert_eq!(f.pixel(32, 24), Some([255, 0, 0, 255]), "{}", r.name());
    }
}

#[test]
fn splat_sizes_cover_the_right_pixels() {
    let white = pack_rgb(255, 255, 255);
    for mut r in all_renderers() {
        for size in 1..=3u32 {
            let f = render_points(r.as_mut(), &[([0.0, 10.0, 0.0], white)], size);
            let (x0, y0, s) = match size {
                1 => (32, 24, 1),
                2 => (32, 24, 2),
                _ => (31, 23, 3),
            };
            for y in 0..49 {
                for x in 0..65 {
                    let inside = (x0..x0 + s).contains(&x) && (y0..y0 + s).contains(&y);
                    let px = f.pixel(x, y).unwrap();
                    assert_eq!(!is_bg(&px), inside, "{} size {size} at ({x},{y})", r.name());
                }
            }
        }
        // Clamped sizes: 0 → 1, 9 → 3.
        let f0 = render_points(r.as_mut(), &[([0.0, 10.0, 0.0], white)], 0);
        assert_eq!(count_drawn(&f0), 1);
        let f9 = render_points(r.as_mut(), &[([0.0, 10.0, 0.0], white)], 9);
        assert_eq!(count_drawn(&f9), 9);
        // A splat at the frame corner is cut, not wrapped.
        let corner = render_points(r.as_mut(), &[([-11.0, 10.0, 7.0], white)], 3);
        assert!(count_drawn(&corner) <= 9);
    }
}

#[test]
fn clipped_points_are_not_drawn() {
    let c = pack_rgb(200, 200, 200);
    let pts = [
        ([0.0, -10.0, 0.0], c),          // behind the camera
        ([0.0, 0.0, 0.0], c),            // at the eye
        ([0.0, 0.05, 0.0], c),           // before the near plane
        ([0.0, 5000.0, 0.0], c),         // beyond the far plane
        ([1000.0, 10.0, 0.0], c),        // far right
        ([0.0, 10.0, 1000.0], c),        // far above
        ([f64::NAN, 10.0, 0.0], c),      // garbage
        ([f64::INFINITY, 10.0, 0.0], c), // garbage
    ];
    for mut r in all_renderers() {
        for size in 1..=3 {
            let f = render_points(r.as_mut(), &pts, size);
            assert_eq!(count_drawn(&f), 0, "{} size {size}", r.name());
        }
    }
}

#[test]
fn empty_input_and_bad_options() {
    let cam = axis_camera();
    let empty = PointBatch {
        origin: [0.0; 3],
        x: &[],
        y: &[],
        z: &[],
        color: &[],
    };
    let mut one = Cols::new([0.0; 3]);
    one.push([0.0, 10.0, 0.0], pack_rgb(255, 0, 0));
    for mut r in all_renderers() {
        // A drawn frame first: nothing of it may leak into the next frames.
        let f = r.render(&cam, &[one.batch()], &opts(16, 9, 3)).unwrap();
        assert_eq!(count_drawn(&f), 9);
        for bs in [vec![], vec![empty]] {
            for edl in [false, true] {
                let mut o = opts(16, 9, 2);
                o.eye_dome_lighting = edl;
                let f = r.render(&cam, &bs, &o).unwrap();
                assert_eq!(
                    f,
                    Frame {
                        stats: f.stats,
                        ..Frame::background(16, 9, BG)
                    }
                );
                assert_eq!(f.stats.points_drawn, 0);
            }
        }
        for (w, h) in [(0, 10), (10, 0), (0, 0), (100_000, 10)] {
            assert!(matches!(
                r.render(&cam, &[], &opts(w, h, 1)),
                Err(RenderError::InvalidOptions(_))
            ));
        }
        let bad = PointBatch {
            origin: [0.0; 3],
            x: &[1.0, 2.0],
            y: &[1.0],
            z: &[1.0, 2.0],
            color: &[0, 0],
        };
        assert!(matches!(
            r.render(&cam, &[bad], &opts(8, 8, 1)),
            Err(RenderError::InvalidInput(_))
        ));
        let nan_origin = PointBatch {
            origin: [f64::NAN, 0.0, 0.0],
            ..empty
        };
        assert!(r.render(&cam, &[nan_origin], &opts(8, 8, 1)).is_err());
        // A degenerate camera still renders (nothing or something, no panic).
        let weird = Camera {
            near: -1.0,
            far: f64::NAN,
            fov_y: 0.0,
            ..Camera::default()
        };
        let mut c = Cols::new([0.0; 3]);
        c.push([0.0, 1.0, 0.0], 5);
        assert!(r.render(&weird, &[c.batch()], &opts(8, 8, 1)).is_ok());
    }
}

#[test]
fn frame_size_changes_between_frames() {
    let (cols, bounds) = scene();
    let bs = batches(&cols);
    let cam = Camera::fit(&bounds);
    for mut r in all_renderers() {
        for (w, h) in [(320, 240), (97, 31), (320, 240), (1, 1)] {
            let mut fresh = all_renderers();
            let a = r.render(&cam, &bs, &opts(w, h, 1)).unwrap();
            assert_eq!(a.rgba.len(), (w * h * 4) as usize);
            // Same image as a renderer that never saw another size.
            let kind = r.name();
            let b = fresh
                .iter_mut()
                .find(|f| f.name() == kind)
                .unwrap()
                .render(&cam, &bs, &opts(w, h, 1))
                .unwrap();
            assert_eq!(a.rgba, b.rgba, "{kind} at {w}x{h}");
        }
    }
}

#[test]
fn create_picks_a_renderer() {
    let cpu = create(RendererChoice::Cpu).unwrap();
    assert!(cpu.name().starts_with("cpu ("), "{}", cpu.name());
    let auto = create(RendererChoice::Auto).unwrap();
    assert!(!auto.name().is_empty());
    match create(RendererChoice::Gpu) {
        Ok(g) => assert!(g.name().starts_with("wgpu "), "{}", g.name()),
        Err(e) => {
            assert!(matches!(e, RenderError::NoAdapter(_)));
            assert!(auto.name().starts_with("cpu"));
        }
    }
    assert_eq!(
        "GPU".parse::<RendererChoice>().unwrap(),
        RendererChoice::Gpu
    );
    assert!("tpu".parse::<RendererChoice>().is_err());
}

#[test]
fn save_png_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("f.png");
    // Every pixel back as written (PNG decoded by the image crate).
    let mut f = Frame::background(4, 3, [1, 2, 3]);
    f.rgba[4 * 5..4 * 6].copy_from_slice(&[200, 100, 50, 255]);
    f.save_png(&p).unwrap();
    let back = image::open(&p).unwrap().to_rgba8();
    assert_eq!((back.width(), back.height()), (4, 3));
    assert_eq!(back.as_raw(), &f.rgba);
    assert!(f.save_png(&dir.path().join("no/such/dir.png")).is_err());
}

mod arbitrary {
    use super::*;
    use proptest::prelude::*;

    fn any_f32() -> impl Strategy<Value = f32> {
        prop_oneof![
            8 => -1e3f32..1e3,
            1 => prop::num::f32::ANY,
            1 => Just(f32::NAN),
            1 => Just(f32::INFINITY),
            1 => Just(-1e30f32),
        ]
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            8 => -1e4f64..1e4,
            1 => prop::num::f64::ANY,
            1 => Just(f64::NAN),
        ]
    }

    proptest! {
        // 48 cases unless PROPTEST_CASES says otherwise.
        #![proptest_config(ProptestConfig {
            cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(48),
            ..ProptestConfig::default()
        })]

        /// Any points, any camera, any small frame: an image or an error, never a panic.
        #[test]
        fn renderers_never_panic(
            pts in prop::collection::vec((any_f32(), any_f32(), any_f32(), any::<u32>()), 0..200),
            origin in (any_f64(), any_f64(), any_f64()),
            cam in (any_f64(), any_f64(), any_f64(), any_f64(), any_f64(), any_f64()),
            mode in any::<bool>(),
            size in (0u32..40, 0u32..40, 0u32..6, any::<bool>()),
        ) {
            let x: Vec<f32> = pts.iter().map(|p| p.0).collect();
            let y: Vec<f32> = pts.iter().map(|p| p.1).collect();
            let z: Vec<f32> = pts.iter().map(|p| p.2).collect();
            let c: Vec<u32> = pts.iter().map(|p| p.3).collect();
            let batch = PointBatch { origin: [origin.0, origin.1, origin.2], x: &x, y: &y, z: &z, color: &c };
            let camera = Camera {
                mode: if mode { CameraMode::Orbit } else { CameraMode::Fly },
                target: glam::DVec3::new(cam.0, cam.1, cam.2),
                position: glam::DVec3::new(cam.2, cam.0, cam.1),
                yaw: cam.3,
                pitch: cam.4,
                distance: cam.5,
                fov_y: cam.3,
                near: cam.4,
                far: cam.5,
                ..Camera::default()
            };
            let o = RenderOptions {
                width: size.0,
                height: size.1,
                point_size: size.2,
                eye_dome_lighting: size.3,
                edl: Default::default(),
                background: BG,
            };
            let mut cpu = CpuRasterizer::new();
            let r = cpu.render(&camera, &[batch], &o);
            if let Ok(f) = &r {
                prop_assert_eq!(f.rgba.len(), (o.width * o.height * 4) as usize);
            }
            with_gpu(|gpu| {
                let g = gpu.render(&camera, &[batch], &o);
                assert_eq!(g.is_ok(), r.is_ok());
            });
            let _ = Camera::from_json(&camera.to_json());
            let _ = camera.frustum(1.5).contains_aabb(&Bounds { min: [origin.0; 3], max: [origin.1; 3] });
        }
    }

    proptest! {
        /// Colour modes, EDL, view parsing and camera fitting take anything.
        #[test]
        fn helpers_never_panic(
            v in prop::collection::vec(any_f32(), 0..300),
            pct in (any_f64(), any_f64()),
            range in (any_f64(), any_f64(), any_f64()),
            text in ".{0,20}",
            b in ((any_f64(), any_f64(), any_f64()), (any_f64(), any_f64(), any_f64())),
            w in 0u32..20,
        ) {
            use pcimg::render::{color, edl};
            let _ = color::robust_range(&v, pct.0, pct.1);
            let grey = color::intensity(&v);
            prop_assert_eq!(grey.len(), v.len());
            let mut out = vec![0; v.len()];
            color::intensity_with_range(&v, pct.0 as f32, pct.1 as f32, &mut out);
            let _ = color::height(&v, range.0, range.1, range.2);
            let _ = color::height_auto(&v, range.0);
            let _ = color::rgb_scaled(&v, &v, &v, pct.0 as f32);
            let _ = color::turbo(pct.0 as f32);
            let _ = color::level_color(w);
            let h = (v.len() as u32).checked_div(w).unwrap_or(0);
            let mut img = vec![200u8; (w * h * 4) as usize];
            edl::apply(&mut img, &v[..(w * h) as usize], w, h, &edl::EdlParams { strength: pct.0 as f32, radius: w });
            let _ = pcimg::render::camera::parse_view(&text);
            let _ = Camera::from_json(&text);
            let bounds = Bounds { min: [(b.0).0, (b.0).1, (b.0).2], max: [(b.1).0, (b.1).1, (b.1).2] };
            let mut cam = Camera::fit(&bounds);
            cam.rotate(pct.0, pct.1);
            cam.zoom(range.0);
            cam.translate(range.0, range.1, range.2);
            cam.set_clip_from_bounds(&bounds);
            let _ = cam.view_proj(bounds.min);
            let _ = cam.frustum(pct.0).contains_aabb(&bounds);
            let _ = cam.project(bounds.max, w, w);
            let _ = cam.pixels_per_unit(range.0, w);
        }
    }
}
