//! CPU time of the Hilbert layout's two in-memory phases on a synthetic scan, the
//! medians of several runs: `cargo run --release --example arrange_phases -- 8000000 7`
//! (points, runs). Run with `RAYON_NUM_THREADS=1` for the cost of one core, which
//! a shared machine's load disturbs less than wall time.
use pcimg::store::write::layout::{self, Positions};

fn main() {
    let mut args = std::env::args().skip(1);
    let n: u64 = args
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(8_000_000);
    let runs: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(7);
    let cloud = pcimg::synth::scene_in_order(n, 1, pcimg::synth::Order::Scan);
    let b = cloud.bounds();
    let origin = b.center();
    let pos: Vec<[f32; 3]> = (0..cloud.len())
        .map(|i| {
            let p = [cloud.x[i], cloud.y[i], cloud.z[i]];
            [0, 1, 2].map(|a| (p[a] - origin[a]) as f32)
        })
        .collect();
    drop(cloud);
    let lo = [0, 1, 2].map(|a| (b.min[a] - origin[a]) as f32);
    let hi = [0, 1, 2].map(|a| (b.max[a] - origin[a]) as f32);
    let levels = layout::representative_levels(pos.len());
    let (mut sort, mut arrange) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        let t = cpu_seconds();
        let mut perm = layout::hilbert_order(Positions::Held(&pos), lo, hi);
        let t1 = cpu_seconds();
        let (out, _) = layout::gather_representatives(
            Positions::Held(&pos),
            &mut perm,
            levels,
            lo,
            hi,
            &|_, _, _, _| {},
            layout::Keep::All,
        );
        let t2 = cpu_seconds();
        std::hint::black_box(out);
        sort.push(t1 - t);
        arrange.push(t2 - t1);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let per = |s: f64| s / n as f64 * 1e9;
    let (s, a) = (median(&mut sort), median(&mut arrange));
    println!(
        "{n} points, {} threads, CPU medians of {runs}: sort {s:.3} s ({:.1} ns a point), \
         gather+representatives {a:.3} s ({:.1} ns a point)",
        rayon::current_num_threads(),
        per(s),
        per(a)
    );
}

/// User + system CPU time of this process.
fn cpu_seconds() -> f64 {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given.
    let u = unsafe {
        libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr());
        u.assume_init()
    };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}
