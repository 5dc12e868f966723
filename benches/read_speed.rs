//! Read speed of a converted dataset from the page cache: every part's level 0
//! (or `--level N`), bands `x y z` (or `--bands a,b,..`), read `--reps` times
//! after one warm-up read; prints the median and range in M points/s. The
//! figure behind "read ≥ 300 M points/s" (issue 40, bench/RESULTS.md).
//!
//! ```text
//! cargo run --release --example read_speed -- DATASET [--level N] [--bands x,y,z] [--reps 7]
//! ```
//!
//! A check as well: the first read's coordinates must equal every later one's.

use pcimg_store::Dataset;
use std::path::PathBuf;
use std::time::Instant;

/// The allocator `pcimg` itself runs with (its library installs it): large
/// blocks recycled, not faulted in fresh for every read. Without it a read of
/// a whole level spent a quarter of its time zeroing new pages.
#[cfg(target_os = "linux")]
#[global_allocator]
static GLOBAL: pcimg_core::alloc::Recycling = pcimg_core::alloc::Recycling;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let mut path = None;
    let (mut level, mut bands, mut reps) = (0usize, "x,y,z".to_string(), 7usize);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--level" => level = args.next().ok_or("--level N")?.parse()?,
            "--bands" => bands = args.next().ok_or("--bands a,b")?,
            "--reps" => reps = args.next().ok_or("--reps N")?.parse()?,
            _ => path = Some(PathBuf::from(a)),
        }
    }
    let Some(path) = path else {
        eprintln!("usage: read_speed DATASET [--level N] [--bands x,y,z] [--reps 7]");
        std::process::exit(2);
    };
    let ds = Dataset::open(&path)?;
    let names: Vec<&str> = bands.split(',').collect();
    // Every part's points, timed; then (untimed) their sum, to compare reads.
    let read_all = || -> Result<(usize, f64, f64), Box<dyn std::error::Error>> {
        let t = Instant::now();
        let mut read = Vec::with_capacity(ds.part_count());
        for part in ds.parts().unwrap() {
            let l = level.min(part.levels.len().saturating_sub(1));
            read.push(part.read_level(l, &part.band_indices(&names)?)?);
        }
        let s = t.elapsed().as_secs_f64();
        let n = read.iter().map(|p| p.len()).sum();
        let sum = read
            .iter()
            .flat_map(|p| &p.columns)
            .map(|c| c.iter().map(|&v| v as f64).sum::<f64>())
            .sum();
        Ok((n, sum, s))
    };
    let (n, first, _) = read_all()?;
    let mut rates = Vec::with_capacity(reps);
    for _ in 0..reps {
        let (m, sum, s) = read_all()?;
        assert!(m == n && sum == first, "a read differed from the first");
        rates.push(n as f64 / s / 1e6);
    }
    rates.sort_by(f64::total_cmp);
    println!(
        "{}: level {level}, bands {bands}: {n} points, {:.1} M points/s median ({:.1}-{:.1}), {} reads",
        path.display(),
        rates[rates.len() / 2],
        rates[0],
        rates[rates.len() - 1],
        reps
    );
    Ok(())
}
