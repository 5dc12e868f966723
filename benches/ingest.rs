//! Input reader throughput: text (x y z intensity), binary PLY and LAS/LAZ.
//!
//! Run: `cargo bench --bench ingest -- --sample-size 10`. Criterion reports MB/s
//! (throughput in bytes); the point count of each file is printed at setup, so
//! M points/s = points / median time. `text_xyzi_1thread` reads the text file on
//! a one-thread rayon pool: the per-thread parsing rate. Inputs are generated in
//! a temporary folder (~500 MB); `PCIMG_BENCH_KEEP=DIR` keeps them in DIR.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pcimg::ingest::{self, ReadOptions};

/// Reads a whole file chunk by chunk, returning the point count.
fn read_points(path: &Path) -> usize {
    let mut r = ingest::open(path, &ReadOptions::default()).expect("open");
    let mut n = 0;
    while let Some(c) = r.next_chunk().expect("chunk") {
        n += c.len();
    }
    n
}

/// A cheap deterministic pseudo-random sequence.
fn lcg(s: &mut u64) -> f64 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

fn write_text(path: &Path, target_bytes: u64) -> usize {
    let mut w = BufWriter::with_capacity(1 << 20, std::fs::File::create(path).expect("create"));
    let mut s = 1u64;
    let mut bytes = 0u64;
    let mut n = 0;
    while bytes < target_bytes {
        let line = format!(
            "{:.3} {:.3} {:.3} {}\n",
            636000.0 + lcg(&mut s) * 1200.0,
            848900.0 + lcg(&mut s) * 600.0,
            400.0 + lcg(&mut s) * 120.0,
            (lcg(&mut s) * 255.0) as u32
        );
        w.write_all(line.as_bytes()).expect("write");
        bytes += line.len() as u64;
        n += 1;
    }
    w.flush().expect("flush");
    n
}

fn write_ply(path: &Path, n: usize) {
    let mut w = BufWriter::with_capacity(1 << 20, std::fs::File::create(path).expect("create"));
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty double x\n\
         property double y\nproperty double z\nproperty uchar red\nproperty uchar green\n\
         property uchar blue\nproperty int label\nend_header\n"
    )
    .expect("write");
    let mut s = 2u64;
    for _ in 0..n {
        for v in [
            lcg(&mut s) * 1000.0,
            lcg(&mut s) * 1000.0,
            lcg(&mut s) * 100.0,
        ] {
            w.write_all(&v.to_le_bytes()).expect("write");
        }
        let c = (lcg(&mut s) * 255.0) as u8;
        w.write_all(&[c, c / 2, c / 3]).expect("write");
        w.write_all(&((c % 7) as i32).to_le_bytes()).expect("write");
    }
    w.flush().expect("flush");
}

fn write_las(path: &Path, n: usize) {
    let mut b = las::Builder::default();
    b.version = las::Version::new(1, 2);
    b.point_format = las::point::Format::new(3).expect("format");
    let t = |o| las::Transform {
        scale: 0.01,
        offset: o,
    };
    b.transforms = las::Vector {
        x: t(636000.0),
        y: t(848900.0),
        z: t(0.0),
    };
    let header = b.into_header().expect("header");
    let mut w = las::Writer::from_path(path, header).expect("writer");
    let mut s = 3u64;
    for i in 0..n {
        let c = (lcg(&mut s) * 255.0) as u16;
        w.write_point(las::Point {
            x: 636000.0 + lcg(&mut s) * 1200.0,
            y: 848900.0 + lcg(&mut s) * 600.0,
            z: 400.0 + lcg(&mut s) * 120.0,
            intensity: c,
            return_number: 1,
            number_of_returns: 1,
            gps_time: Some(300_000_000.0 + i as f64 * 1e-5),
            color: Some(las::Color::new(c * 257, c * 200, c * 100)),
            ..Default::default()
        })
        .expect("write point");
    }
    w.close().expect("close");
}

fn bench(c: &mut Criterion) {
    // PCIMG_BENCH_KEEP=DIR writes the inputs to DIR and keeps them (for profiling).
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = match std::env::var_os("PCIMG_BENCH_KEEP") {
        Some(d) => {
            std::fs::create_dir_all(&d).expect("create PCIMG_BENCH_KEEP");
            PathBuf::from(d)
        }
        None => tmp.path().to_path_buf(),
    };
    let files: Vec<(&str, PathBuf)> = vec![
        ("text_xyzi", dir.join("cloud.xyz")),
        ("ply_binary_le", dir.join("cloud.ply")),
        ("las_pf3", dir.join("cloud.las")),
        ("laz_pf3", dir.join("cloud.laz")),
    ];
    let text_points = write_text(&files[0].1, 200 << 20);
    write_ply(&files[1].1, 5_000_000);
    write_las(&files[2].1, 4_000_000);
    write_las(&files[3].1, 1_000_000);
    let counts = [text_points, 5_000_000, 4_000_000, 1_000_000];
    let mut g = c.benchmark_group("ingest");
    for ((name, path), &points) in files.iter().zip(&counts) {
        let bytes = std::fs::metadata(path).expect("stat").len();
        eprintln!(
            "{name}: {points} points, {:.1} MB (M points/s = {:.3} / median seconds)",
            bytes as f64 / 1e6,
            points as f64 / 1e6
        );
        assert_eq!(read_points(path), points);
        g.throughput(Throughput::Bytes(bytes));
        g.bench_function(*name, |b| b.iter(|| read_points(path)));
        if *name == "text_xyzi" {
            // The same on one rayon thread: the per-thread parsing rate.
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .expect("pool");
            g.bench_function("text_xyzi_1thread", |b| {
                b.iter(|| one.install(|| read_points(path)))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
