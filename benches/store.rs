//! Store throughput: writing 10 M points (sort + layout + pyramid + write; points in
//! random order, and in scan order for uncompressed parts) and
//! reading level 0 and level 2 back, uncompressed, Deflate, Zstd and the LERC codecs
//! (coordinates within 5 mm), from the page cache;
//! and filling a part's builder from a spatial conversion's temporary region file
//! (2.5 M points, x y z intensity: a part of `--memory 256MiB`), through decoded
//! `f64` columns against straight from the packed records.
//!
//! `cargo bench --bench store` (set `PCIMG_BENCH_POINTS` for another size,
//! `PCIMG_BENCH_CODECS=none,lerc_zstd` for some codecs only;
//! `cargo bench --bench store -- read-back` for the builder fill alone).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pcimg::convert::spill::{SpillReader, SpillWriter, records_by_region};
use pcimg::store::{Compression, Part, PartBuilder, WriteOptions, write_part};
use std::time::{Duration, Instant};

fn points() -> u64 {
    std::env::var("PCIMG_BENCH_POINTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000)
}

/// Whether codec `name` is measured: all, or those `PCIMG_BENCH_CODECS` lists
/// (`none,lerc_zstd`), so a run measuring one codec does not write the others.
fn wanted(name: &str) -> bool {
    std::env::var("PCIMG_BENCH_CODECS").map_or(true, |l| l.split(',').any(|c| c == name))
}

fn bench(c: &mut Criterion) {
    let n = points();
    let cloud = pcimg::synth::scene(n, 1);
    let scan = pcimg::synth::scene_in_order(n, 1, pcimg::synth::Order::Scan);
    let dir = tempfile::tempdir().unwrap();
    let mut g = c.benchmark_group("store");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.throughput(Throughput::Elements(n));
    for comp in Compression::ALL.into_iter().filter(|c| wanted(c.name())) {
        let path = dir.path().join(format!("{}.tif", comp.name()));
        let opts = WriteOptions {
            compression: comp,
            // LERC: coordinates within 5 mm, as a LAS file's of scale 0.01.
            coord_max_error: [0.005; 3],
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

/// A part's worth of points spilled as a region file, then read back into a
/// builder: as `f64` columns pushed (decode, then convert) and as packed records.
fn read_back(c: &mut Criterion) {
    let n = 2_500_000u64;
    let cloud = pcimg::synth::scene_in_order(n, 1, pcimg::synth::Order::Scan);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("region.bin");
    let origin = cloud.bounds().center();
    let (records, _, _) = records_by_region(&cloud, &vec![0u32; n as usize], &[origin]);
    let mut w = SpillWriter::create(path.clone(), 1 << 20, 0).unwrap();
    w.push_records(&records, n).unwrap();
    w.finish().unwrap();
    let like = cloud.empty_like();
    let names: Vec<(String, f64)> = like
        .attributes
        .iter()
        .map(|a| (a.name.clone(), a.offset))
        .collect();
    let part = dir.path().join("part.tif");
    let mut g = c.benchmark_group("read-back");
    g.sample_size(20).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements(n));
    g.bench_function("columns", |b| {
        b.iter(|| {
            let mut r = SpillReader::open(&path, 1).unwrap();
            let mut p = PartBuilder::new(origin, None, n as usize);
            while let Some(c) = r.next_block(&like, usize::MAX, origin).unwrap() {
                p.push(&part, &c).unwrap();
            }
            p
        })
    });
    g.bench_function("packed", |b| {
        b.iter(|| {
            let mut r = SpillReader::open(&path, 1).unwrap();
            let mut p = PartBuilder::new(origin, None, n as usize);
            while let Some(rec) = r.next_records(usize::MAX).unwrap() {
                p.push_packed(&part, rec, &names).unwrap();
            }
            p
        })
    });
    g.finish();
}

criterion_group!(benches, read_back, bench);
criterion_main!(benches);
