//! Choosing the COPC reader by measurement (issue 42): every point of a COPC
//! file read by (a) our reader (`pcimg-copc` + `pcimg-ingest`: nodes fetched
//! as one batch, decompressed and decoded into columns in parallel), (b) the
//! `las` crate's `CopcReader::query` (every node, decompressed into its
//! `PointData`, one after the other), and (c) the LAZ the COPC was made from
//! through our LAZ reader, interleaved, REPS rounds (default 15): median and
//! range in M points/s.
//!
//!   cargo run --release --example copc_read -- [COPC] [LAZ]

use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let copc = args
        .first()
        .cloned()
        .unwrap_or_else(|| "fixtures/autzen_trim.copc.laz".into());
    let laz = args.get(1).cloned();
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(15);
    let ours = || {
        let mut r = pcimg::ingest::copc::open(
            std::path::Path::new(&copc),
            &pcimg::ingest::ReadOptions::default(),
        )
        .unwrap();
        let mut n = 0u64;
        while let Some(c) = pcimg::ingest::PointReader::next_chunk(&mut r).unwrap() {
            n += c.len() as u64;
        }
        n
    };
    let las_crate = || {
        let mut r = las::CopcReader::from_path(&copc).unwrap();
        let pd = r
            .query(las::LodSelection::All, las::BoundsSelection::All)
            .unwrap();
        pd.len() as u64
    };
    let laz_reader = |p: &str| {
        let mut r = pcimg::ingest::open(
            std::path::Path::new(p),
            &pcimg::ingest::ReadOptions::default(),
        )
        .unwrap();
        let mut n = 0u64;
        while let Some(c) = r.next_chunk().unwrap() {
            n += c.len() as u64;
        }
        n
    };
    let mut runs: Vec<(&str, Vec<f64>)> =
        vec![("ours (pcimg-copc)", vec![]), ("las::CopcReader", vec![])];
    if laz.is_some() {
        runs.push(("the LAZ, our LAS/LAZ reader", vec![]));
    }
    let mut points = 0;
    for _ in 0..reps {
        for (k, run) in runs.iter_mut().enumerate() {
            let t = Instant::now();
            points = match k {
                0 => ours(),
                1 => las_crate(),
                _ => laz_reader(laz.as_deref().unwrap_or_default()),
            };
            run.1.push(points as f64 / t.elapsed().as_secs_f64() / 1e6);
        }
    }
    println!("{copc}: {points} points, {reps} interleaved rounds");
    for (name, mut v) in runs {
        v.sort_by(f64::total_cmp);
        println!(
            "  {name:<30} median {:.1} M points/s ({:.1}-{:.1})",
            v[v.len() / 2],
            v[0],
            v[v.len() - 1]
        );
    }
}
