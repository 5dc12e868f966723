//! The paper's Table 2 for a dataset: per level, points, loading time (all parts,
//! x y z, from the page cache) and frames per second of the CPU and wgpu
//! rasterizers at 1280×720 (median of 5 frames, data already uploaded).
//!
//! `cargo run --release --example level_table -- DATASET`
use pcimg::camera::Camera;
use pcimg::render::{self, PointBatch, RenderOptions, RendererChoice};
use pcimg::store::Dataset;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: level_table DATASET"))?;
    let ds = Dataset::open(std::path::Path::new(&path))?;
    let levels = ds.parts.iter().map(|p| p.levels.len()).max().unwrap_or(0);
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
        ds.parts.len()
    );
    println!("renderers: {}", names.join(" | "));
    println!(
        "| level | points | load ms (median of 3) | {} |",
        names
            .iter()
            .map(|n| format!("fps {n}"))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    println!("|---|---|---|{}", "---|".repeat(names.len()));
    for level in (0..levels).rev() {
        let mut loads = Vec::new();
        let mut data = Vec::new();
        for _ in 0..3 {
            let t = Instant::now();
            data = ds
                .parts
                .iter()
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
        println!(
            "| {level} | {points} | {:.0} | {} |",
            median(loads),
            fps.join(" | ")
        );
    }
    Ok(())
}
