//! The paper's Table 2 for a dataset: per level, points, loading time (all parts,
//! x y z, from the page cache) and frames per second of the CPU and wgpu
//! rasterizers at 1280×720 (median of 5 frames, data already uploaded).
//!
//! With `--paper`, the paper's Table 2 (Du & Li 2009: LOD3…LOD0 and the original,
//! GeForce 7300 GT) is printed beside ours: our level k ≥ 1 stands for its
//! LOD(k − 1), level 0 for the original.
//!
//! `cargo run --release --example level_table -- DATASET [--paper]`
use pcimg::camera::Camera;
use pcimg::render::{self, PointBatch, RenderOptions, RendererChoice};
use pcimg::store::Dataset;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The paper's Table 2: (name, points, loading ms, fps), finest last.
const PAPER: [(&str, u64, u64, u64); 5] = [
    ("LOD3", 187_810, 129, 60),
    ("LOD2", 748_525, 439, 40),
    ("LOD1", 2_988_239, 1686, 35),
    ("LOD0", 11_943_853, 4496, 12),
    ("original", 47_775_412, 30408, 2),
];

/// The paper's row for our `level`.
fn paper_row(level: usize) -> Option<(&'static str, u64, u64, u64)> {
    match level {
        0 => Some(PAPER[4]),
        1..=4 => Some(PAPER[4 - level]),
        _ => None,
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let paper = args.iter().any(|a| a == "--paper");
    let path = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("usage: level_table DATASET [--paper]"))?;
    let ds = Dataset::open(std::path::Path::new(&path))?;
    let levels = ds
        .parts()
        .unwrap()
        .into_iter()
        .map(|p| p.levels.len())
        .max()
        .unwrap_or(0);
    let cam = {
        let mut c = Camera::fit(&ds.bounds());
        c.set_clip_from_bounds(&ds.bounds());
        c
    };
    let opts = RenderOptions::default();
    let mut renderers: Vec<Box<dyn render::Rasterizer>> =
        vec![render::create(RendererChoice::Cpu)?];
    match render::create(RendererChoice::Gpu) {
        Ok(r) => renderers.push(r),
        Err(e) => eprintln!("no wgpu adapter: {e}"),
    }
    let names: Vec<String> = renderers.iter().map(|r| r.name()).collect();
    println!(
        "dataset {path}: {} points in {} parts",
        ds.points(),
        ds.part_count()
    );
    println!("renderers: {}", names.join(" | "));
    let fps_names = names
        .iter()
        .map(|n| format!("fps {}", n.split(" (").next().unwrap_or(n)))
        .collect::<Vec<_>>()
        .join(" | ");
    if paper {
        println!(
            "| level | points | paper's level (points) | load ms (median of 3) | paper load ms | {fps_names} | paper fps |"
        );
        println!("|---|---|---|---|---|{}---|", "---|".repeat(names.len()));
    } else {
        println!("| level | points | load ms (median of 3) | {fps_names} |");
        println!("|---|---|---|{}", "---|".repeat(names.len()));
    }
    for level in (0..levels).rev() {
        let mut loads = Vec::new();
        let mut data = Vec::new();
        for _ in 0..3 {
            let t = Instant::now();
            data = ds
                .parts()
                .unwrap()
                .into_iter()
                .map(|p| p.read_level(level.min(p.levels.len() - 1), &[0, 1, 2]))
                .collect::<Result<Vec<_>, _>>()?;
            loads.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let points: usize = data.iter().map(|d| d.len()).sum();
        let colors: Vec<Vec<u32>> = data.iter().map(|d| vec![0xffc0c0c0u32; d.len()]).collect();
        let batches: Vec<PointBatch> = data
            .iter()
            .zip(&colors)
            .map(|(d, c)| PointBatch {
                origin: [d.offsets[0], d.offsets[1], d.offsets[2]],
                x: &d.columns[0],
                y: &d.columns[1],
                z: &d.columns[2],
                color: c,
            })
            .collect();
        let mut fps = Vec::new();
        for r in renderers.iter_mut() {
            r.render(&cam, &batches, &opts)?; // upload / warm up
            let times: Vec<f64> = (0..5)
                .map(|_| {
                    let t = Instant::now();
                    let _ = r.render(&cam, &batches, &opts);
                    t.elapsed().as_secs_f64()
                })
                .collect();
            fps.push(format!("{:.1}", 1.0 / median(times)));
        }
        let load = median(loads);
        if paper {
            let (pl, pms, pfps) = match paper_row(level) {
                Some((n, p, ms, f)) => (
                    format!("{n} ({})", pcimg::text::count(p)),
                    ms.to_string(),
                    f.to_string(),
                ),
                None => ("–".into(), "–".into(), "–".into()),
            };
            println!(
                "| {level} | {} | {pl} | {load:.1} | {pms} | {} | {pfps} |",
                pcimg::text::count(points as u64),
                fps.join(" | ")
            );
        } else {
            println!("| {level} | {points} | {load:.1} | {} |", fps.join(" | "));
        }
    }
    Ok(())
}
