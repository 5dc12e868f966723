//! Level-of-detail quality (the paper's stated limitation, issue 6): for each level,
//! the distance from every point of the full cloud to its nearest point of the level
//! (mean and 95th percentile), for our layout and the paper's layout (both written
//! and read back through the store), a uniform random sample and a voxel-grid sample
//! (one point per cell, the one nearest the cell centre, cell size bisected to the
//! same count within 1%). Prints a markdown table.
//!
//! Levels the part stores are read from it; deeper levels (small clouds store few)
//! are the stride-`4^k` subset of level 0 that a larger pyramid would keep (ours:
//! every `4^k`-th point of the Z-order curve; paper: rows and columns that are
//! multiples of `2^k`), checked against the stored levels first.
//!
//! ```text
//! cargo run --release --example lod_quality -- [--levels 5] [--min-points 100] INPUT...
//! INPUT: a point cloud file, synth:N (synthetic scene, random order) or
//!        synth-scan:N (the same points in airborne scan order)
//! cargo run --release --example lod_quality -- --dataset DIR
//! ```
//!
//! `--dataset DIR` measures a directory dataset's levels as a viewer draws them
//! over the whole dataset: each level of the parts' pyramids (every part's level
//! `k`, or its coarsest where it has fewer), then each layer of the overview above
//! them (every node of the layer), against a voxel-grid sample of the same size
//! (issue 26: the overview must be as even as the parts' own levels).
use anyhow::{Context, bail};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use pcimg::ingest::{self, ReadOptions};
use pcimg::points::PointColumns;
use pcimg::store::write::paper;
use pcimg::store::{Dataset, Layout, Part, WriteOptions, write_part};
use pcimg::synth::{self, Order, Rng};
use rayon::prelude::*;
use std::path::Path;

type P3 = [f64; 3];

/// Mean and 95th percentile of the distance from every point of `cloud` to its
/// nearest point of `sample`.
fn coverage(cloud: &[P3], sample: &[P3]) -> (f64, f64) {
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(sample);
    let mut d: Vec<f64> = cloud
        .par_iter()
        .map(|q| tree.nearest_one::<SquaredEuclidean>(q).distance.sqrt())
        .collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let k = ((d.len() as f64 * 0.95) as usize).min(d.len() - 1);
    let (_, p95, _) = d.select_nth_unstable_by(k, f64::total_cmp);
    (mean, *p95)
}

/// `m` distinct points of `cloud`, uniformly at random (partial Fisher–Yates).
fn random_sample(cloud: &[P3], m: usize, seed: u64) -> Vec<P3> {
    let mut idx: Vec<u32> = (0..cloud.len() as u32).collect();
    let mut r = Rng::new(seed);
    for i in 0..m {
        let j = i + (r.next_u64() % (idx.len() - i) as u64) as usize;
        idx.swap(i, j);
    }
    idx[..m].iter().map(|&i| cloud[i as usize]).collect()
}

/// Cell keys of a grid of cell size `c` from `lo` (21 bits per axis).
fn cell_keys(cloud: &[P3], lo: P3, c: f64) -> Vec<u64> {
    cloud
        .par_iter()
        .map(|p| {
            let q = |a: usize| (((p[a] - lo[a]) / c) as u64).min((1 << 21) - 1);
            q(0) | (q(1) << 21) | (q(2) << 42)
        })
        .collect()
}

fn occupied(cloud: &[P3], lo: P3, c: f64) -> usize {
    let mut k = cell_keys(cloud, lo, c);
    k.par_sort_unstable();
    k.dedup();
    k.len()
}

/// A voxel-grid sample of about `m` points: the cell size is bisected (on a log
/// scale) until the occupied cells are within 1% of `m`; each cell keeps the point
/// nearest its centre.
fn voxel_sample(cloud: &[P3], m: usize) -> Vec<P3> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in cloud {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max).max(1e-9);
    let (mut small, mut large) = (extent / (1 << 20) as f64, extent);
    let mut best = (usize::MAX, large);
    for _ in 0..60 {
        let c = (small * large).sqrt();
        let n = occupied(cloud, lo, c);
        if n.abs_diff(m) < best.0.abs_diff(m) {
            best = (n, c);
        }
        if n.abs_diff(m) * 100 <= m {
            break;
        }
        if n > m {
            small = c;
        } else {
            large = c;
        }
    }
    let c = best.1;
    let keys = cell_keys(cloud, lo, c);
    let mut order: Vec<(u64, f64, u32)> = keys
        .par_iter()
        .enumerate()
        .map(|(i, &k)| {
            let p = cloud[i];
            let d: f64 = (0..3)
                .map(|a| {
                    let cell = ((k >> (21 * a)) & ((1 << 21) - 1)) as f64;
                    (p[a] - (lo[a] + (cell + 0.5) * c)).powi(2)
                })
                .sum();
            (k, d, i as u32)
        })
        .collect();
    order.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    order.dedup_by_key(|e| e.0);
    order.iter().map(|e| cloud[e.2 as usize]).collect()
}

/// Points of a level read through the store, relative to `centre`.
fn read(part: &Part, level: usize, centre: P3) -> anyhow::Result<Vec<P3>> {
    let p = part.read_level(level, &[0, 1, 2])?;
    Ok((0..p.len())
        .map(|i| [0, 1, 2].map(|a| p.offsets[a] + p.columns[a][i] as f64 - centre[a]))
        .collect())
}

fn load(spec: &str) -> anyhow::Result<(String, PointColumns)> {
    for (prefix, order, label) in [
        ("synth:", Order::Random, "synthetic, random order"),
        ("synth-scan:", Order::Scan, "synthetic, scan order"),
    ] {
        if let Some(n) = spec.strip_prefix(prefix) {
            let n: u64 = n
                .replace('_', "")
                .parse()
                .context("synth:N needs a count")?;
            return Ok((
                format!("{label} ({n} pts)"),
                synth::scene_in_order(n, 1, order),
            ));
        }
    }
    let (_, pts, _) = ingest::read_all(Path::new(spec), &ReadOptions::default())?;
    let name = Path::new(spec)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec.to_string());
    Ok((format!("{name} ({} pts)", pts.len()), pts))
}

struct Row {
    level: usize,
    stored: bool,
    points: usize,
    paper_points: usize,
    ours: (f64, f64),
    paper: (f64, f64),
    random: (f64, f64),
    voxel: (f64, f64),
    voxel_points: usize,
}

fn evaluate(pts: &PointColumns, levels: usize, min_points: usize) -> anyhow::Result<Vec<Row>> {
    let dir = tempfile::tempdir()?;
    let write = |layout: Layout, name: &str| -> anyhow::Result<Part> {
        let path = dir.path().join(name);
        let opts = WriteOptions {
            layout,
            ..Default::default()
        };
        write_part(&path, pts, &opts)?;
        Ok(Part::open(&path)?)
    };
    let ours = write(Layout::Hilbert, "ours.tif")?;
    let theirs = write(Layout::Paper, "paper.tif")?;
    let centre = ours.meta.bounds.center();
    // Level 0 of the paper's part is the cloud in input order.
    let cloud = read(&theirs, 0, centre)?;
    let ours0 = read(&ours, 0, centre)?;
    let n = cloud.len();
    let mut rows = Vec::new();
    for k in 1..=levels {
        let ours_k: Vec<P3> = ours0.iter().step_by(1 << (2 * k)).copied().collect();
        let paper_k: Vec<P3> = paper::level_indices(n as u64, k)
            .iter()
            .map(|&i| cloud[i as usize])
            .collect();
        let stored = k < ours.levels.len();
        if stored {
            // The derivation above is what the store keeps.
            if read(&ours, k, centre)? != ours_k || read(&theirs, k, centre)? != paper_k {
                bail!("level {k} read from the store differs from the stride rule");
            }
        }
        if ours_k.len() < min_points {
            break;
        }
        let m = ours_k.len();
        let voxel = voxel_sample(&cloud, m);
        rows.push(Row {
            level: k,
            stored,
            points: m,
            paper_points: paper_k.len(),
            ours: coverage(&cloud, &ours_k),
            paper: coverage(&cloud, &paper_k),
            random: coverage(&cloud, &random_sample(&cloud, m, k as u64)),
            voxel: coverage(&cloud, &voxel),
            voxel_points: voxel.len(),
        });
    }
    Ok(rows)
}

/// Every level of a dataset as drawn over all of it, against a voxel sample.
fn evaluate_dataset(dir: &Path) -> anyhow::Result<()> {
    let ds = Dataset::open(dir)?;
    let centre = ds.bounds().center();
    let union = |parts: &[&Part], level: Option<usize>| -> anyhow::Result<Vec<P3>> {
        let mut out = Vec::new();
        for p in parts {
            let top = p.levels.len() - 1;
            out.extend(read(p, level.unwrap_or(top).min(top), centre)?);
        }
        Ok(out)
    };
    let parts: Vec<&Part> = ds.parts().unwrap().into_iter().collect();
    let cloud = union(&parts, Some(0))?;
    let own = ds.own_levels();
    let mut samples: Vec<(String, Vec<P3>)> = Vec::new();
    for k in 1..own {
        samples.push((format!("parts' level {k}"), union(&parts, Some(k))?));
    }
    if ds.has_overview() {
        for layer in 1..=ds.layer_count() {
            let nodes: Vec<&Part> = ds
                .layer_nodes(layer)?
                .into_iter()
                .filter_map(|id| ds.part(id))
                .collect();
            samples.push((
                format!("overview layer {layer} ({} nodes)", nodes.len()),
                union(&nodes, None)?,
            ));
        }
    }
    println!(
        "{}: {} parts, {} points. Distance from every point to the nearest point of the \
         level: mean / p95; ratio = level ÷ voxel sample of the same size.",
        dir.display(),
        ds.part_count(),
        cloud.len()
    );
    println!();
    println!(
        "| level | points | level mean / p95 | random | voxel (points) | ÷ voxel mean / p95 |"
    );
    println!("|---|---|---|---|---|---|");
    for (k, (name, sample)) in samples.iter().enumerate() {
        let voxel = voxel_sample(&cloud, sample.len());
        let (ours, vox) = (coverage(&cloud, sample), coverage(&cloud, &voxel));
        let random = coverage(&cloud, &random_sample(&cloud, sample.len(), k as u64));
        let f = |v: (f64, f64)| format!("{} / {}", sig(v.0), sig(v.1));
        println!(
            "| {name} | {} | {} | {} | {} ({}) | {:.2} / {:.2} |",
            sample.len(),
            f(ours),
            f(random),
            f(vox),
            voxel.len(),
            ours.0 / vox.0,
            ours.1 / vox.1
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let mut levels = 5usize;
    let mut min_points = 100usize;
    let mut inputs = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--levels" => levels = args.next().context("--levels N")?.parse()?,
            "--min-points" => min_points = args.next().context("--min-points N")?.parse()?,
            "--dataset" => {
                return evaluate_dataset(Path::new(&args.next().context("--dataset DIR")?));
            }
            _ => inputs.push(a),
        }
    }
    if inputs.is_empty() {
        bail!(
            "usage: lod_quality [--levels K] [--min-points M] INPUT... (file, synth:N, synth-scan:N)"
        );
    }
    println!(
        "Distance from every point to the nearest point of the level (dataset units): mean / p95. \
         ratio = ours ÷ voxel. goal: ours below paper and random, ratio ≤ 1.20 (both figures). \
         * = level beyond the stored pyramid (stride of level 0)."
    );
    println!();
    println!(
        "| dataset | level | points | ours | paper (points) | random | voxel (points) | ours÷voxel mean / p95 | goal |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for spec in &inputs {
        let t = std::time::Instant::now();
        let (name, pts) = load(spec).with_context(|| format!("loading {spec}"))?;
        let rows = evaluate(&pts, levels, min_points).with_context(|| spec.clone())?;
        for r in &rows {
            let f = |v: (f64, f64)| format!("{} / {}", sig(v.0), sig(v.1));
            let ratio = (r.ours.0 / r.voxel.0, r.ours.1 / r.voxel.1);
            let ok = r.ours.0 < r.paper.0
                && r.ours.1 < r.paper.1
                && r.ours.0 < r.random.0
                && r.ours.1 < r.random.1
                && ratio.0 <= 1.2
                && ratio.1 <= 1.2;
            println!(
                "| {name} | {}{} | {} | {} | {} ({}) | {} | {} ({}) | {:.2} / {:.2} | {} |",
                r.level,
                if r.stored { "" } else { "*" },
                r.points,
                f(r.ours),
                f(r.paper),
                r.paper_points,
                f(r.random),
                f(r.voxel),
                r.voxel_points,
                ratio.0,
                ratio.1,
                if ok { "met" } else { "**missed**" }
            );
        }
        eprintln!("{spec}: {:.1} s", t.elapsed().as_secs_f64());
    }
    Ok(())
}

/// Three significant digits.
fn sig(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}
