//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod fuzz;
pub mod proxy;
pub mod http;
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
        max_error: None,
        layout: pcimg::store::Layout::Hilbert,
        read: pcimg::ingest::ReadOptions::default(),
        allow_lossy: false,
        cancel: std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false)),
        sample_points: pcimg::convert::DEFAULT_SAMPLE_POINTS,
        io: pcimg::store::TileIo::Auto,
        on_part: None,
    }
}
