//! Store throughput: writing 10 M points (sort + layout + pyramid + write; points in
//! random order, and in scan order for uncompressed parts) and
//! reading level 0 and level 2 back, uncompressed and Deflate, from the page cache.
//!
//! `cargo bench --bench store` (set `PCIMG_BENCH_POINTS` for another size).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pcimg::store::{Compression, Part, WriteOptions, write_part};
use std::time::{Duration, Instant};

fn points() -> u64 {
    std::env::var("PCIMG_BENCH_POINTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000)
}

fn bench(c: &mut Criterion) {
    let n = points();
    let cloud = pcimg::synth::scene(n, 1);
    let scan = pcimg::synth::scene_in_order(n, 1, pcimg::synth::Order::Scan);
    let dir = tempfile::tempdir().unwrap();
    let mut g = c.benchmark_group("store");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.throughput(Throughput::Elements(n));
    for comp in [Compression::None, Compression::Deflate] {
        let path = dir.path().join(format!("{}.tif", comp.name()));
        let opts = WriteOptions {
            compression: comp,
            ..Default::default()
        };
        write_part(&path, &cloud, &opts).unwrap();
        // Each iteration writes a new file, as a conversion does; the previous one
        // is removed outside the timing (replacing a file would add the kernel's
        // freeing of its cached pages to the rename, ~0.1 s at 10 M points).
        let fresh = |c: &pcimg::points::PointColumns, iters: u64| {
            let mut total = Duration::ZERO;
            for i in 0..iters {
                let p = dir.path().join(format!("w{i}.tif"));
                let t = Instant::now();
                write_part(&p, c, &opts).unwrap();
                total += t.elapsed();
                std::fs::remove_file(&p).unwrap();
            }
            total
        };
        g.bench_function(format!("write/{}/{n}", comp.name()), |b| {
            b.iter_custom(|iters| fresh(&cloud, iters))
        });
        if comp == Compression::None {
            // Points in the order an airborne scanner records them (real files).
            g.bench_function(format!("write-scan-order/{}/{n}", comp.name()), |b| {
                b.iter_custom(|iters| fresh(&scan, iters))
            });
        }
        let part = Part::open(&path).unwrap();
        for level in [0usize, 2] {
            let pts = part.levels[level].points.unwrap();
            g.throughput(Throughput::Elements(pts));
            g.bench_function(format!("read-xyz/{}/level{level}", comp.name()), |b| {
                b.iter(|| part.read_level(level, &[0, 1, 2]).unwrap())
            });
            g.bench_function(format!("read-all/{}/level{level}", comp.name()), |b| {
                b.iter(|| part.read_level(level, &[0, 1, 2, 3]).unwrap())
            });
        }
        g.throughput(Throughput::Elements(n));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
