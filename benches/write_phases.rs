//! Prints the time of each phase of writing a synthetic part:
//! `cargo run --release --example write_phases -- 10000000 none [random|scan]`
//! (wall time per run and per phase, and the CPU time the run used; each run
//! writes a new file)
fn main() {
    let mut args = std::env::args().skip(1);
    let n: u64 = args
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000);
    let comp = pcimg::store::Compression::parse(&args.next().unwrap_or("none".into())).unwrap();
    let order = pcimg::synth::Order::parse(&args.next().unwrap_or("random".into())).unwrap();
    let cloud = pcimg::synth::scene_in_order(n, 1, order);
    let dir = tempfile::tempdir().unwrap();
    let opts = pcimg::store::WriteOptions {
        compression: comp,
        ..Default::default()
    };
    for run in 0..3 {
        // Each run writes a new file, as a conversion does; replacing an existing
        // one would add the kernel's freeing of its cached pages (~0.1 s for 10 M
        // points here) to the rename.
        let path = dir.path().join(format!("p{run}.tif"));
        let (cu, cs) = cpu_seconds();
        let t = std::time::Instant::now();
        let s = pcimg::store::write_part(&path, &cloud, &opts).unwrap();
        let total = t.elapsed().as_secs_f64();
        let (u, sy) = cpu_seconds();
        let (user, sys) = (u - cu, sy - cs);
        std::fs::remove_file(&path).unwrap();
        let phases: Vec<String> = s
            .phases
            .iter()
            .map(|(n, d)| format!("{n} {:.0} ms", d.wall.as_secs_f64() * 1e3))
            .collect();
        println!(
            "{:.2} s, CPU {:.2} s (user {user:.2}, sys {sys:.2}) ({:.1} M points/s): {}",
            total,
            user + sys,
            n as f64 / total / 1e6,
            phases.join(", ")
        );
    }
}

/// User and system CPU time of this process (a load-independent cost measure on a
/// shared machine; wall time is what the targets are about).
fn cpu_seconds() -> (f64, f64) {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given.
    let u = unsafe {
        libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr());
        u.assume_init()
    };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    (t(u.ru_utime), t(u.ru_stime))
}
