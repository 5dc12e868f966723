//! Writes the synthetic scene as the inputs of `bench/e57_pcd.sh`: binary and
//! binary_compressed PCD, E57 with float and with scaled-integer coordinates
//! (the `e57` crate's writer), and LAS, all of the same points (the LAS file
//! in the scene's georeferenced frame, the others in its local frame).
//!
//! ```text
//! cargo run --release --example make_e57_pcd -- [--points 20000000] [--dir /tmp/pcimg-e57pcd]
//! ```
use pcimg::synth_formats::{PcdData, write_e57, write_pcd};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let mut points = 20_000_000u64;
    let mut dir = PathBuf::from("/tmp/pcimg-e57pcd");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--points" => points = args.next().unwrap_or_default().parse()?,
            "--dir" => dir = PathBuf::from(args.next().unwrap_or_default()),
            other => anyhow::bail!("unknown argument {other}"),
        }
    }
    std::fs::create_dir_all(&dir)?;
    let seed = 1;
    let timed = |name: &str, f: &dyn Fn(&std::path::Path) -> anyhow::Result<()>| {
        let p = dir.join(name);
        let t = Instant::now();
        f(&p)?;
        let bytes = std::fs::metadata(&p)?.len();
        println!(
            "{} {:.1} MB in {:.1} s",
            p.display(),
            bytes as f64 / 1e6,
            t.elapsed().as_secs_f64()
        );
        anyhow::Ok(())
    };
    timed("scene.pcd", &|p| {
        Ok(write_pcd(p, points, seed, PcdData::Binary).map(|_| ())?)
    })?;
    timed("scene_z.pcd", &|p| {
        Ok(write_pcd(p, points, seed, PcdData::Compressed).map(|_| ())?)
    })?;
    timed("scene_f.e57", &|p| {
        Ok(write_e57(p, points, seed, false, 1)?)
    })?;
    timed("scene_i.e57", &|p| Ok(write_e57(p, points, seed, true, 1)?))?;
    timed("scene.las", &|p| {
        Ok(pcimg::synth::write_las(p, points, seed).map(|_| ())?)
    })?;
    Ok(())
}
