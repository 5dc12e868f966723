//! A national-scale dataset without a national dataset (issue 44): `N` small real
//! parts, each a square tile of a survey on a grid over a large area (1,000 m tiles:
//! 100,000 parts cover 316 × 316 km), written through the store library as
//! `pcimg convert` writes a LAS tile (zstd, coordinates on a centimetre lattice,
//! the LAS attributes a survey carries), then indexed as `pcimg index` does
//! unless `--no-index`.
//!
//! ```text
//! cargo run --release --example many_parts -- DIR N [--points MIN:MAX] [--seed S] [--no-index]
//! ```
//!
//! Points per part are drawn evenly from MIN..MAX (default 1000:10000), so parts
//! differ as tiles of a real survey do (edges, water). DIR must not exist.
use anyhow::{Context, bail};
use pcimg::points::{Attribute, Lattice, PointColumns};
use pcimg::store::dataset::overview::{IndexOptions, build_index};
use pcimg::store::{Compression, WriteOptions, write_part};
use pcimg::synth::Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// Side of one part's square, metres.
const TILE: f64 = 1000.0;

/// The points of tile (`i`, `j`): ground with a slope and hills, a few buildings'
/// roofs, LAS attributes (intensity, returns, class, gps_time) on a 1 cm lattice.
fn tile(i: usize, j: usize, n: usize, seed: u64) -> PointColumns {
    let mut r = Rng::new(seed ^ ((i as u64) << 32 | j as u64));
    let names = [
        "intensity",
        "return_number",
        "number_of_returns",
        "classification",
        "gps_time",
    ];
    let mut c = PointColumns {
        attributes: names
            .iter()
            .map(|n| Attribute::new(*n, Vec::new()))
            .collect(),
        ..Default::default()
    };
    let (x0, y0) = (400_000.0 + i as f64 * TILE, 5_000_000.0 + j as f64 * TILE);
    let t0 = 300_000_000.0 + (j * 1000 + i) as f64 * 7.0;
    for k in 0..n {
        let (dx, dy) = (r.f64() * TILE, r.f64() * TILE);
        let (x, y) = (x0 + dx, y0 + dy);
        let ground = 50.0 + 0.002 * (x - 400_000.0) + 8.0 * (x / 700.0).sin() * (y / 900.0).cos();
        let roof = (dx % 200.0 < 40.0) && (dy % 250.0 < 30.0);
        let z = if roof { ground + 12.0 } else { ground };
        let round = |v: f64| (v * 100.0).round() / 100.0;
        c.x.push(round(x));
        c.y.push(round(y));
        c.z.push(round(z));
        let a = &mut c.attributes;
        a[0].values.push((r.f64() * 400.0).floor() as f32);
        a[1].values.push(1.0);
        a[2].values.push(1.0);
        a[3].values.push(if roof { 6.0 } else { 2.0 });
        a[4].values.push((k as f64 * 1e-4) as f32);
    }
    c.attributes[4].offset = t0;
    c
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut pos = Vec::new();
    let (mut lo, mut hi, mut seed, mut index) = (1000usize, 10_000usize, 1u64, true);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--points" => {
                let v = it.next().context("--points MIN:MAX")?;
                let (a, b) = v.split_once(':').context("--points MIN:MAX")?;
                (lo, hi) = (a.parse()?, b.parse()?);
            }
            "--seed" => seed = it.next().context("--seed S")?.parse()?,
            "--no-index" => index = false,
            _ => pos.push(a.clone()),
        }
    }
    let [dir, n] = pos.as_slice() else {
        bail!("usage: many_parts DIR N [--points MIN:MAX] [--seed S] [--no-index]");
    };
    let n: usize = n.parse().context("N: a number of parts")?;
    if n == 0 || lo == 0 || hi < lo {
        bail!("need N > 0 and 0 < MIN <= MAX");
    }
    let dir = PathBuf::from(dir);
    if dir.exists() {
        bail!("{}: exists; give a new directory", dir.display());
    }
    std::fs::create_dir_all(&dir)?;
    let side = (n as f64).sqrt().ceil() as usize;
    let opts = WriteOptions {
        compression: Compression::Zstd,
        crs: Some("EPSG:32631".into()),
        lattice: Some(Lattice {
            step: [0.01; 3],
            origin: [0.0; 3],
        }),
        ..Default::default()
    };
    let t0 = Instant::now();
    let done = AtomicUsize::new(0);
    let points: u64 = (0..n)
        .into_par_iter()
        .map(|k| -> anyhow::Result<u64> {
            let mut r = Rng::new(seed.wrapping_mul(0x9E37_79B9) ^ k as u64);
            let count = lo + (r.f64() * (hi - lo + 1) as f64) as usize;
            let c = tile(k % side, k / side, count.min(hi), seed);
            let path = dir.join(format!("tile-{:04}-{:04}.tif", k % side, k / side));
            write_part(&path, &c, &opts).with_context(|| path.display().to_string())?;
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            if d.is_multiple_of(10_000) {
                eprintln!("{d} parts written, {:.1} s", t0.elapsed().as_secs_f64());
            }
            Ok(c.len() as u64)
        })
        .sum::<anyhow::Result<u64>>()?;
    eprintln!(
        "{n} parts, {points} points written in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    if index {
        index_dir(&dir)?;
    }
    Ok(())
}

fn index_dir(dir: &Path) -> anyhow::Result<()> {
    let t = Instant::now();
    let r = build_index(dir, &IndexOptions::default(), &|_| {})?;
    eprintln!(
        "indexed: {} parts, {} nodes in {} layers, index {} bytes, {:.1} s",
        r.parts,
        r.nodes,
        r.layers,
        r.index_bytes,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
