//! Rasterization throughput at 1280×720 for a synthetic terrain-like cloud of
//! 1 M and 10 M points in three orders: Morton-sorted (as the store delivers
//! them), Morton-sorted with blocks of 10240 points shuffled (Schütz et al.'s
//! "shuffled Morton", which spreads atomic contention on GPUs) and fully
//! shuffled. CPU (both framebuffer strategies) and wgpu (when an adapter exists).
//!
//! `cargo bench --bench render -- --sample-size 10`

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group};
use rayon::slice::ParallelSliceMut;

use pcimg::points::Bounds;
use pcimg::render::color::pack_rgb;
use pcimg::render::cpu::{CpuRasterizer, CpuStrategy};
use pcimg::render::gpu::{GpuOptions, GpuRasterizer};
use pcimg::render::{Camera, PointBatch, Rasterizer, RenderOptions};

#[derive(Clone)]
struct Cloud {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    c: Vec<u32>,
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn spread(v: u32) -> u64 {
    let mut x = v as u64 & 0xffff_ffff;
    x = (x | (x << 16)) & 0x0000_ffff_0000_ffff;
    x = (x | (x << 8)) & 0x00ff_00ff_00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    x = (x | (x << 1)) & 0x5555_5555_5555_5555;
    x
}

const SIZE: f32 = 2000.0;

/// Terrain over a 2 km square: rolling hills, coloured by height, Morton-sorted.
fn terrain(n: usize) -> Cloud {
    let mut r = Rng(0x2545_f491_4f6c_dd1d);
    let mut pts: Vec<(u64, f32, f32, f32)> = (0..n)
        .map(|_| {
            let (x, y) = (r.f() * SIZE, r.f() * SIZE);
            let z = 40.0 * (x * 0.004).sin() * (y * 0.003).cos()
                + 8.0 * (x * 0.03 + y * 0.02).sin()
                + r.f() * 0.5;
            let key =
                spread((x / SIZE * 65535.0) as u32) | spread((y / SIZE * 65535.0) as u32) << 1;
            (key, x, y, z)
        })
        .collect();
    // In parallel: 500 M points take a minute on one core of the lent GPU machine.
    pts.par_sort_unstable_by_key(|p| p.0);
    let mut c = Cloud {
        x: Vec::with_capacity(n),
        y: Vec::with_capacity(n),
        z: Vec::with_capacity(n),
        c: Vec::with_capacity(n),
    };
    for (_, x, y, z) in pts {
        c.x.push(x);
        c.y.push(y);
        c.z.push(z);
        let t = ((z + 50.0) / 100.0).clamp(0.0, 1.0);
        c.c.push(pack_rgb((255.0 * t) as u8, 120, (255.0 * (1.0 - t)) as u8));
    }
    c
}

fn permute(c: &Cloud, perm: &[usize]) -> Cloud {
    Cloud {
        x: perm.iter().map(|&i| c.x[i]).collect(),
        y: perm.iter().map(|&i| c.y[i]).collect(),
        z: perm.iter().map(|&i| c.z[i]).collect(),
        c: perm.iter().map(|&i| c.c[i]).collect(),
    }
}

fn shuffle<T>(v: &mut [T], r: &mut Rng) {
    for i in (1..v.len()).rev() {
        let j = (r.next() % (i as u64 + 1)) as usize;
        v.swap(i, j);
    }
}

fn shuffled(c: &Cloud) -> Cloud {
    let mut perm: Vec<usize> = (0..c.x.len()).collect();
    shuffle(&mut perm, &mut Rng(7));
    permute(c, &perm)
}

fn block_shuffled(c: &Cloud, block: usize) -> Cloud {
    let n = c.x.len();
    let mut blocks: Vec<usize> = (0..n.div_ceil(block)).collect();
    shuffle(&mut blocks, &mut Rng(11));
    let perm: Vec<usize> = blocks
        .iter()
        .flat_map(|&b| b * block..((b + 1) * block).min(n))
        .collect();
    permute(c, &perm)
}

fn bench(cr: &mut Criterion) {
    let opts = RenderOptions {
        width: 1280,
        height: 720,
        point_size: 1,
        eye_dome_lighting: false,
        edl: Default::default(),
        background: [0, 0, 0],
    };
    let bounds = Bounds {
        min: [500_000.0, 4_000_000.0, -60.0],
        max: [500_000.0 + SIZE as f64, 4_000_000.0 + SIZE as f64, 60.0],
    };
    let cam = Camera::fit(&bounds);
    let mut renderers: Vec<(String, Box<dyn Rasterizer>)> = vec![
        (
            "cpu".into(),
            Box::new(CpuRasterizer::with_strategy(CpuStrategy::PerThread)),
        ),
        (
            "cpu_atomic".into(),
            Box::new(CpuRasterizer::with_strategy(CpuStrategy::SharedAtomic)),
        ),
    ];
    match GpuRasterizer::new() {
        Ok(g) => {
            eprintln!(
                "gpu: {} (64-bit atomics: {})",
                g.name(),
                g.has_int64_atomics()
            );
            renderers.push(("gpu".into(), Box::new(g)));
        }
        Err(e) => eprintln!("no wgpu adapter, GPU benchmarks skipped: {e}"),
    }
    // Fixed per-frame cost: clear, merge/resolve, readback of an empty frame.
    let mut g = cr.benchmark_group("render_empty_frame");
    for (name, r) in renderers.iter_mut() {
        g.bench_function(name.as_str(), |b| {
            b.iter(|| r.render(&cam, &[], &opts).is_ok())
        });
    }
    g.finish();
    for n in [1_000_000usize, 10_000_000] {
        let morton = terrain(n);
        let orders = [
            ("morton", morton.clone()),
            ("morton_blocks_shuffled", block_shuffled(&morton, 10_240)),
            ("shuffled", shuffled(&morton)),
        ];
        let mut g = cr.benchmark_group(format!("render_{}M", n / 1_000_000));
        g.throughput(Throughput::Elements(n as u64));
        for (order, cloud) in &orders {
            let batch = PointBatch {
                origin: [bounds.min[0], bounds.min[1], 0.0],
                x: &cloud.x,
                y: &cloud.y,
                z: &cloud.z,
                color: &cloud.c,
            };
            for (name, r) in renderers.iter_mut() {
                // Warm-up frame uploads (GPU) and allocates framebuffers.
                if let Err(e) = r.render(&cam, &[batch], &opts) {
                    eprintln!("{name} {order}: {e}");
                    continue;
                }
                g.bench_function(BenchmarkId::new(name.as_str(), order), |b| {
                    b.iter(|| {
                        r.render(&cam, &[batch], &opts)
                            .map(|f| f.stats.points_drawn)
                    })
                });
            }
        }
        g.finish();
    }
}

/// Colour modes on 10 M values.
fn bench_color(cr: &mut Criterion) {
    use pcimg::render::color;
    let n = 10_000_000usize;
    let mut r = Rng(3);
    let v: Vec<f32> = (0..n).map(|_| r.f() * 65535.0).collect();
    let z: Vec<f32> = (0..n).map(|_| r.f() * 100.0).collect();
    let rgb: Vec<f32> = (0..n).map(|_| r.f() * 255.0).collect();
    let mut g = cr.benchmark_group("color_10M");
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function("intensity", |b| b.iter(|| color::intensity(&v)));
    g.bench_function("height", |b| {
        b.iter(|| color::height(&z, 300.0, 300.0, 400.0))
    });
    g.bench_function("rgb", |b| b.iter(|| color::rgb(&rgb, &rgb, &rgb)));
    g.finish();
}

criterion_group!(benches, bench, bench_color);

/// The wgpu shader variants `ab` compares: `ppt<N>` points per invocation,
/// `+pretest` the depth pre-test, `+merge` per-invocation run merging, `+sg`
/// the subgroup reduction, `+seg` its segmented minimum.
fn variants() -> Vec<(String, GpuOptions)> {
    let mut v: Vec<(String, GpuOptions)> = vec![("default".into(), GpuOptions::default())];
    let combos = [
        (8, true, false, false, false),
        (32, true, false, false, false),
        (16, true, true, false, false),
        (32, true, true, false, false),
        (64, true, true, false, false),
        (32, false, true, false, false),
        (1, true, false, true, false),
        (4, true, false, true, false),
        (8, true, false, true, false),
        (16, true, false, true, false),
        (8, false, false, true, false),
        (8, true, false, true, true),
        (16, true, false, true, true),
    ];
    v.extend(combos.into_iter().map(|(ppt, pre, merge, sg, seg)| {
        (
            format!(
                "ppt{ppt}{}{}{}{}",
                if pre { "+pretest" } else { "" },
                if merge { "+merge" } else { "" },
                if sg { "+sg" } else { "" },
                if seg { "+seg" } else { "" },
            ),
            GpuOptions {
                points_per_thread: ppt,
                no_early_depth_test: !pre,
                merge_runs: Some(merge),
                subgroups: Some(sg),
                segmented_runs: seg,
                ..Default::default()
            },
        )
    }));
    v
}

/// `PCIMG_RENDER_AB=1 cargo bench --bench render` (or `=<points>`): interleaved A/B of wgpu
/// shader variants, best of several frames each (robust on a shared machine).
/// `PCIMG_RENDER_VARIANTS=default,ppt8+pretest+sg` picks variants (all by
/// default), `PCIMG_RENDER_ORDERS=morton` the point orders, `PCIMG_RENDER_CPU=0`
/// leaves the CPU rasterizers out, `PCIMG_RENDER_ROUNDS` sets the rounds (7).
fn ab() {
    let pick = std::env::var("PCIMG_RENDER_VARIANTS").ok();
    let picked = |name: &str| {
        pick.as_deref()
            .is_none_or(|p| p.split(',').any(|n| n == name))
    };
    let mut gpus: Vec<(String, GpuRasterizer)> = variants()
        .into_iter()
        .filter(|(n, _)| picked(n))
        .filter_map(|(n, o)| match GpuRasterizer::with_options(o) {
            Ok(g) => {
                if o.subgroups == Some(true) && !g.has_subgroups() {
                    eprintln!("{n}: no subgroups on {}, left out", g.name());
                    return None;
                }
                Some((n, g))
            }
            Err(e) => {
                eprintln!("{n}: {e}");
                None
            }
        })
        .collect();
    if let Some((_, g)) = gpus.first() {
        println!("gpu: {}", g.name());
    }
    let with_cpu = std::env::var("PCIMG_RENDER_CPU").map_or(true, |v| v != "0");
    let mut cpus: Vec<(&str, CpuRasterizer)> = if with_cpu {
        vec![
            ("cpu", CpuRasterizer::with_strategy(CpuStrategy::PerThread)),
            (
                "cpu_atomic",
                CpuRasterizer::with_strategy(CpuStrategy::SharedAtomic),
            ),
        ]
    } else {
        Vec::new()
    };
    let rounds = std::env::var("PCIMG_RENDER_ROUNDS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .unwrap_or(7);
    let order_pick = std::env::var("PCIMG_RENDER_ORDERS").ok();
    let opts = RenderOptions {
        width: 1280,
        height: 720,
        ..Default::default()
    };
    let bounds = Bounds {
        min: [500_000.0, 4_000_000.0, -60.0],
        max: [500_000.0 + SIZE as f64, 4_000_000.0 + SIZE as f64, 60.0],
    };
    let cam = Camera::fit(&bounds);
    // PCIMG_RENDER_AB=<points> (default 10 M).
    let n = std::env::var("PCIMG_RENDER_AB")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&n| n > 1)
        .unwrap_or(10_000_000);
    let morton = terrain(n);
    let want = |o: &str| {
        order_pick
            .as_deref()
            .is_none_or(|p| p.split(',').any(|n| n == o))
    };
    let mut orders: Vec<(&str, Cloud)> = Vec::new();
    if want("morton_blocks_shuffled") {
        orders.push(("morton_blocks_shuffled", block_shuffled(&morton, 10_240)));
    }
    if want("shuffled") {
        orders.push(("shuffled", shuffled(&morton)));
    }
    if want("morton") {
        orders.insert(0, ("morton", morton));
    } else {
        drop(morton);
    }
    for (order, c) in &orders {
        let batch = PointBatch {
            origin: [bounds.min[0], bounds.min[1], 0.0],
            x: &c.x,
            y: &c.y,
            z: &c.z,
            color: &c.c,
        };
        let mut best = vec![f64::INFINITY; gpus.len() + cpus.len()];
        let mut all = vec![Vec::new(); gpus.len()];
        for _ in 0..rounds {
            for (k, (name, g)) in gpus.iter_mut().enumerate() {
                // One frame untimed first: whatever ran before (the CPU renderers)
                // has the caches, and the first variant of a round would pay.
                let _ = g.render(&cam, &[batch], &opts);
                match g.render(&cam, &[batch], &opts) {
                    Ok(f) => {
                        best[k] = best[k].min(f.stats.render_ms);
                        all[k].push(f.stats.render_ms);
                    }
                    Err(e) => eprintln!("{name}: {e}"),
                }
            }
            for (k, (_, c)) in cpus.iter_mut().enumerate() {
                if let Ok(f) = c.render(&cam, &[batch], &opts) {
                    let k = gpus.len() + k;
                    best[k] = best[k].min(f.stats.render_ms);
                }
            }
        }
        let names = gpus
            .iter()
            .map(|g| g.0.as_str())
            .chain(cpus.iter().map(|c| c.0));
        for (k, (name, ms)) in names.zip(&best).enumerate() {
            let spread = match all.get_mut(k) {
                Some(v) if !v.is_empty() => {
                    v.sort_by(f64::total_cmp);
                    format!(
                        "  median {:.2} ms, range {:.2}-{:.2}",
                        v[v.len() / 2],
                        v[0],
                        v[v.len() - 1]
                    )
                }
                _ => String::new(),
            };
            println!(
                "{order:24} {name:26} {ms:8.2} ms {:9.1} M points/s{spread}",
                n as f64 / ms / 1e3
            );
        }
    }
}

/// `PCIMG_RENDER_IDS=<points> cargo bench --bench render`: the CPU and (where
/// an adapter exists) wgpu rasterizers without and with the per-pixel id
/// buffer picking reads (`keep_ids`),
/// interleaved, 15 rounds; the median and range of each frame's time.
fn ab_ids(n: usize) {
    let opts = RenderOptions {
        width: 1280,
        height: 720,
        ..Default::default()
    };
    let bounds = Bounds {
        min: [500_000.0, 4_000_000.0, -60.0],
        max: [500_000.0 + SIZE as f64, 4_000_000.0 + SIZE as f64, 60.0],
    };
    let cam = Camera::fit(&bounds);
    let c = terrain(n);
    let batch = PointBatch {
        origin: [bounds.min[0], bounds.min[1], 0.0],
        x: &c.x,
        y: &c.y,
        z: &c.z,
        color: &c.c,
    };
    let mut rs: Vec<(String, Box<dyn Rasterizer>)> = vec![
        ("cpu".into(), Box::new(CpuRasterizer::new())),
        ("cpu+ids".into(), Box::new(CpuRasterizer::new())),
    ];
    for ids in [false, true] {
        match GpuRasterizer::new() {
            Ok(g) => {
                if !ids {
                    println!("gpu: {}", g.name());
                }
                let name = if ids { "gpu+ids" } else { "gpu" };
                rs.push((name.into(), Box::new(g)));
            }
            Err(e) => {
                eprintln!("no wgpu adapter, GPU rows skipped: {e}");
                break;
            }
        }
    }
    for (name, r) in rs.iter_mut() {
        r.keep_ids(name.ends_with("+ids"));
    }
    let mut runs = vec![Vec::new(); rs.len()];
    for round in 0..16 {
        for (k, (_, r)) in rs.iter_mut().enumerate() {
            let f = r.render(&cam, &[batch], &opts).expect("frame");
            // The first round warms caches, allocations and uploads.
            if round > 0 {
                runs[k].push(f.stats.render_ms);
            }
        }
    }
    for ((name, _), mut v) in rs.iter().zip(runs) {
        v.sort_by(f64::total_cmp);
        println!(
            "{n} points {name:8} median {:7.1} ms, range {:.1}-{:.1} ms ({} frames)",
            v[v.len() / 2],
            v[0],
            v[v.len() - 1],
            v.len()
        );
    }
}

fn main() {
    if let Some(n) = std::env::var("PCIMG_RENDER_IDS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    {
        ab_ids(n.max(1));
        return;
    }
    if std::env::var_os("PCIMG_RENDER_AB").is_some() {
        ab();
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
