//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod cli;
pub mod fuzz;
pub mod http;
pub mod proxy;
pub mod pty;
pub mod servers;
pub mod tiffwalk;
pub mod tmux;

use pcimg::points::{Attribute, PointColumns};
use pcimg::synth::Rng;
use std::process::Command;

/// Whether an external tool runs. In CI (`CI=true`) a missing tool is a failure,
/// never a skip; elsewhere the caller skips with a note.
pub fn tool_available(program: &str, arg: &str) -> bool {
    let ok = Command::new(program)
        .arg(arg)
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var("CI").ok().as_deref() != Some("true"),
            "{program} is required in CI (.ci/run installs it: gdal-bin, tmux)"
        );
        eprintln!("note: {program} not found, skipping this test outside CI");
    }
    ok
}

/// A random cloud near georeferenced coordinates, with duplicates.
pub fn random_cloud(n: usize, seed: u64, dup_every: usize) -> PointColumns {
    let mut r = Rng::new(seed);
    let mut c = PointColumns {
        attributes: vec![
            Attribute::new("intensity", Vec::new()),
            Attribute {
                name: "gps_time".into(),
                offset: 3.1e8,
                values: Vec::new(),
            },
        ],
        ..Default::default()
    };
    for i in 0..n {
        if dup_every > 0 && i > 0 && i % dup_every == 0 {
            let j = (r.next_u64() % i as u64) as usize;
            c.x.push(c.x[j]);
            c.y.push(c.y[j]);
            c.z.push(c.z[j]);
            for a in &mut c.attributes {
                let v = a.values[j];
                a.values.push(v);
            }
            continue;
        }
        c.x.push(637179.22 + r.f64() * 500.0);
        c.y.push(6010946.56 + r.f64() * 300.0);
        c.z.push(20.51 + r.f64() * 30.0);
        c.attributes[0].values.push((r.f64() * 255.0) as f32);
        c.attributes[1].values.push((r.f64() * 100.0) as f32);
    }
    c
}

/// Points as exact bit patterns of (f64 coordinates, f32 attributes), sorted.
pub fn multiset(rows: Vec<Vec<u64>>) -> Vec<Vec<u64>> {
    let mut rows = rows;
    rows.sort();
    rows
}

/// The values of attribute `name` (the test fails when there is none).
pub fn attr<'a>(p: &'a PointColumns, name: &str) -> &'a [f32] {
    &p.attributes
        .iter()
        .find(|a| a.name == name)
        .unwrap_or_else(|| panic!("no attribute {name}"))
        .values
}

/// `convert`'s options with every default but the output and the memory budget.
pub fn convert_options(output: std::path::PathBuf, memory: u64) -> pcimg::convert::ConvertOptions {
    pcimg::convert::ConvertOptions {
        output,
        force: false,
        memory,
        partition: pcimg::convert::Partition::Spatial,
        compression: pcimg::store::Compression::None,
        zstd_level: None,
        max_error: None,
        precision: None,
        layout: pcimg::store::Layout::Hilbert,
        read: pcimg::ingest::ReadOptions::default(),
        allow_lossy: false,
        cancel: std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false)),
        sample_points: pcimg::convert::DEFAULT_SAMPLE_POINTS,
        io: pcimg::store::TileIo::Auto,
        on_part: None,
    }
}

/// What a command run on a small tmpfs did: its output, and the files on the
/// tmpfs (paths relative to it, sorted) after the setup and after the command.
pub struct OnTmpfs {
    pub output: std::process::Output,
    pub before: Vec<String>,
    pub after: Vec<String>,
}

/// Whether a private mount namespace with a tmpfs can be made here (`unshare
/// --user --map-root-user --mount`, then `mount -t tmpfs`): as root, or where
/// user namespaces are allowed. In CI (`CI=true`) a refusal is a failure;
/// elsewhere the caller skips with a note.
pub fn tmpfs_available() -> bool {
    let probe = tempfile::tempdir().unwrap();
    let ok = Command::new("unshare")
        .args(["--user", "--map-root-user", "--mount", "sh", "-c"])
        .arg("mount -t tmpfs -o size=1m tmpfs \"$0\"")
        .arg(probe.path())
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var("CI").ok().as_deref() != Some("true"),
            "CI=true and unshare/mount cannot make a private tmpfs (user namespaces refused?)"
        );
        eprintln!("note: unshare or mount refused, skipping this test outside CI");
    }
    ok
}

/// Runs `program args` with a tmpfs of `size` (e.g. `4m`) mounted at `mount`
/// (an empty directory) in a private mount namespace, so the mount is gone
/// when the command ends, whatever happens. `setup` (shell, `$T` the mount
/// point) runs first, e.g. to copy a dataset there or fill the disk; `then`
/// (shell) runs after the command, its output appended to the command's
/// stdout. The files on the tmpfs are listed after the setup and after the
/// command (`then` included).
pub fn on_tmpfs(
    mount: &std::path::Path,
    size: &str,
    setup: &str,
    program: &std::path::Path,
    args: &[&std::ffi::OsStr],
    envs: &[(&str, &std::ffi::OsStr)],
    then: &str,
) -> OnTmpfs {
    let lists = tempfile::tempdir().unwrap();
    let (before, after) = (lists.path().join("before"), lists.path().join("after"));
    let script = format!(
        "T=\"$1\"; B=\"$2\"; A=\"$3\"; shift 3\n\
         mount -t tmpfs -o size={size} tmpfs \"$T\" || exit 97\n\
         {setup}\n\
         (cd \"$T\" && find . -mindepth 1) > \"$B\"\n\
         \"$@\"; rc=$?\n\
         {then}\n\
         (cd \"$T\" && find . -mindepth 1) > \"$A\"\n\
         exit $rc\n"
    );
    let mut c = Command::new("unshare");
    c.args([
        "--user",
        "--map-root-user",
        "--mount",
        "sh",
        "-c",
        &script,
        "sh",
    ])
    .arg(mount)
    .arg(&before)
    .arg(&after)
    .arg(program)
    .args(args);
    for (k, v) in envs {
        c.env(k, v);
    }
    let output = c.output().expect("unshare runs");
    assert_ne!(
        output.status.code(),
        Some(97),
        "the tmpfs could not be mounted: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let list = |p: &std::path::Path| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_to_string(p)
            .unwrap_or_default()
            .lines()
            .map(|l| l.trim_start_matches("./").to_string())
            .collect();
        v.sort();
        v
    };
    OnTmpfs {
        before: list(&before),
        after: list(&after),
        output,
    }
}

/// A file's bytes hashed (FNV-1a), to show an input was left untouched.
pub fn file_hash(path: &std::path::Path) -> u64 {
    let data = std::fs::read(path).unwrap();
    data.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The inspector's render worker on `ds`, as the tests run it: half-block
/// frames, the CPU renderer, a 1 GiB budget, 2 loading threads.
pub fn halfblock_worker(
    ds: std::sync::Arc<pcimg::store::Dataset>,
) -> pcimg::tui::worker::RenderWorker {
    use pcimg::tui::protocol::{Encoding, Graphics};
    pcimg::tui::worker::RenderWorker::spawn(
        ds,
        pcimg::tui::worker::WorkerOptions {
            encoding: Encoding::new(Graphics::Halfblocks),
            extra_bands: Vec::new(),
            renderer: pcimg::render::RendererChoice::Cpu,
            memory: 1 << 30,
            load_threads: 2,
        },
    )
}

/// A Python that imports `modules` (GDAL's bindings from python3-gdal, laspy),
/// or `None` outside CI (a failure in CI: .ci/run installs them).
pub fn python_with(modules: &str) -> Option<&'static str> {
    let found = ["/usr/bin/python3", "python3"].into_iter().find(|py| {
        Command::new(py)
            .args(["-c", &format!("import {modules}")])
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if found.is_none() {
        assert!(
            std::env::var("CI").ok().as_deref() != Some("true"),
            "a python3 that imports {modules} is required in CI (.ci/run installs it)"
        );
        eprintln!("note: no python3 that imports {modules}, skipping this test outside CI");
    }
    found
}

/// `nx` × `ny` parts of a terrain (10 × 10 units each, `per_part` points with
/// intensity), each its own file, written in parallel and indexed.
pub fn grid_dataset(
    dir: &std::path::Path,
    nx: usize,
    ny: usize,
    per_part: usize,
) -> std::path::PathBuf {
    let ds = dir.join(format!("grid-{nx}x{ny}.pcimg"));
    std::fs::create_dir(&ds).unwrap();
    use rayon::prelude::*;
    (0..nx * ny).into_par_iter().for_each(|k| {
        let (i, j) = (k % nx, k / nx);
        let mut r = pcimg::synth::Rng::new(3 + k as u64);
        {
            let mut c = PointColumns {
                attributes: vec![Attribute::new("intensity", Vec::new())],
                ..Default::default()
            };
            for _ in 0..per_part {
                let (x, y) = (i as f64 + r.f64(), j as f64 + r.f64());
                c.x.push(500_000.0 + 10.0 * x);
                c.y.push(4_000_000.0 + 10.0 * y);
                c.z.push(100.0 + (x * 0.7).sin() + (y * 0.3).cos());
                c.attributes[0]
                    .values
                    .push((r.f64() * 255.0).round() as f32);
            }
            let f = ds.join(format!("tile-{i:02}-{j:02}.tif"));
            // (Compressed: 10,000 small parts take 100 MB, not 10 GB.)
            let opts = pcimg::store::WriteOptions {
                compression: pcimg::store::Compression::Zstd,
                ..Default::default()
            };
            pcimg::store::write_part(&f, &c, &opts).unwrap();
        }
    });
    pcimg::store::dataset::overview::build_index(
        &ds,
        &pcimg::store::dataset::overview::IndexOptions::default(),
        &|_| {},
    )
    .unwrap();
    ds
}
