//! Prints the time of each phase of writing a synthetic part:
//! `cargo run --release --example write_phases -- 10000000 none`
fn main() {
    let mut args = std::env::args().skip(1);
    let n: u64 = args
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000);
    let comp = pcimg::store::Compression::parse(&args.next().unwrap_or("none".into())).unwrap();
    let cloud = pcimg::synth::scene(n, 1);
    let dir = tempfile::tempdir().unwrap();
    let opts = pcimg::store::WriteOptions {
        compression: comp,
        ..Default::default()
    };
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let s = pcimg::store::write_part(&dir.path().join("p.tif"), &cloud, &opts).unwrap();
        let total = t.elapsed().as_secs_f64();
        let phases: Vec<String> = s
            .phases
            .iter()
            .map(|(n, d)| format!("{n} {:.0} ms", d.as_secs_f64() * 1e3))
            .collect();
        println!(
            "{:.2} s ({:.1} M points/s): {}",
            total,
            n as f64 / total / 1e6,
            phases.join(", ")
        );
    }
}
