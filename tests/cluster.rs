//! Conversion on a cluster, end to end: `convert --plan`, shards run out of order
//! as plain processes (`xargs -P 2`) and on a Dask LocalCluster (one shard's
//! process killed once, then retried), `pcimg index` checking the receipts; the
//! result compared with a single-process `convert` of the same input.

use pcimg::store::Dataset;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

fn pcimg() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pcimg"))
}

fn run(c: &mut Command) -> String {
    let out = c.output().expect("runs");
    assert!(
        out.status.success(),
        "{c:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A text cloud of `n` points on a centimetre lattice (distinct), with an
/// intensity: stored as f32 around any origin, every coordinate rounds back to
/// its centimetre exactly.
fn write_input(path: &Path, n: u64, seed: u64) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        s >> 33
    };
    for i in 0..n {
        // Distinct points: the index picks the (x, y) cell, z is random.
        let (x, y) = (i % 40_000, i / 40_000);
        let jitter = next() % 7;
        writeln!(
            f,
            "{}.{:02} {}.{:02} {}.{:02} {}",
            (x * 7 + jitter) / 100,
            (x * 7 + jitter) % 100,
            (y * 3) / 100,
            (y * 3) % 100,
            next() % 30,
            next() % 100,
            next() % 256
        )
        .unwrap();
    }
}

/// What must equal between two datasets: points, bounds (cm), the checksum of
/// the sorted (x, y, z, intensity) in cm, and the bands.
#[derive(Debug, PartialEq)]
struct Digest {
    points: u64,
    min: [i64; 3],
    max: [i64; 3],
    checksum: u64,
    bands: Vec<String>,
}

fn digest(dir: &Path) -> Digest {
    let ds = Dataset::open(dir).unwrap();
    let mut all: Vec<[i64; 4]> = Vec::new();
    let mut bands = None;
    for p in ds.parts().unwrap() {
        let names: Vec<String> = p.bands.iter().map(|b| b.name.clone()).collect();
        assert!(bands.is_none() || bands.as_ref() == Some(&names));
        bands = Some(names);
        let pts = p.read_level(0, &[0, 1, 2, 3]).unwrap();
        for i in 0..pts.len() {
            all.push(
                [0, 1, 2, 3]
                    .map(|a| ((pts.offsets[a] + pts.columns[a][i] as f64) * 100.0).round() as i64),
            );
        }
    }
    all.sort_unstable();
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for p in &all {
        for v in p {
            h = pcimg::convert::cluster::fnv1a64(&v.to_le_bytes(), h);
        }
    }
    let (mut min, mut max) = ([i64::MAX; 3], [i64::MIN; 3]);
    for p in &all {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    Digest {
        points: all.len() as u64,
        min,
        max,
        checksum: h,
        bands: bands.unwrap_or_default(),
    }
}

fn single(input: &Path, dir: &Path) -> Digest {
    let out = dir.join("single.pcimg");
    run(pcimg()
        .args(["convert", "-q", "--memory", "64MiB", "-o"])
        .arg(&out)
        .arg(input));
    digest(&out)
}

fn plan(input: &Path, plan: &Path, out: &Path, shards: usize) {
    let said = run(pcimg()
        .args([
            "convert",
            "--memory",
            "64MiB",
            "--shards",
            &shards.to_string(),
        ])
        .arg("--plan")
        .arg(plan)
        .arg("-o")
        .arg(out)
        .arg(input));
    assert!(said.contains(&format!("{shards} shard(s)")), "{said}");
}

fn receipt(out: &Path, i: usize) -> String {
    std::fs::read_to_string(out.join(format!("receipts/shard-{i:05}.json"))).unwrap()
}

#[test]
fn shards_as_plain_processes_out_of_order_equal_one_convert() {
    let t = tempfile::tempdir().unwrap();
    let input = t.path().join("cloud.xyz");
    write_input(&input, 600_000, 3);
    let (p, out) = (t.path().join("plan.json"), t.path().join("out.pcimg"));
    plan(&input, &p, &out, 4);
    // Out of order, two at a time; shard 0 twice at once (an engine's duplicate).
    let order = "2/4 0/4 0/4 1/4";
    let status = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "printf '%s\\n' {order} | xargs -P 2 -I{{}} '{}' convert -q --plan '{}' --shard {{}}",
            env!("CARGO_BIN_EXE_pcimg"),
            p.display()
        ))
        .status()
        .unwrap();
    assert!(status.success());
    // Shard 3 has not run: the finalize names it.
    let e = pcimg().arg("index").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(!e.status.success());
    assert!(
        err.contains("1 of 4 shards have no receipt") && err.contains("shard(s) 3"),
        "{err}"
    );
    assert!(!out.join("pcimg-index.json").exists());
    run(pcimg()
        .args(["convert", "-q", "--plan"])
        .arg(&p)
        .arg("--shard")
        .arg("4")
        .env("SLURM_ARRAY_TASK_ID", "3"));
    // A shard run again writes the same files.
    let before = receipt(&out, 2);
    run(pcimg()
        .args(["convert", "-q", "--plan"])
        .arg(&p)
        .env("JOB_COMPLETION_INDEX", "2"));
    assert_eq!(receipt(&out, 2), before);
    let said = run(pcimg().arg("index").arg(&out));
    assert!(
        said.contains("receipts of 4 shard(s) match the plan"),
        "{said}"
    );
    let got = digest(&out);
    assert_eq!(got.points, 600_000);
    assert_eq!(got, single(&input, t.path()));
    // Every part holds one shard's points only: the receipts add up.
    let listed: u64 = (0..4)
        .map(|i| {
            let r: serde_json::Value = serde_json::from_str(&receipt(&out, i)).unwrap();
            r["points"].as_u64().unwrap()
        })
        .sum();
    assert_eq!(listed, 600_000);
    // A part that lost bytes is named.
    let part = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|e| e == "tif"))
        .unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&part).unwrap();
    f.set_len(100).unwrap();
    let e = pcimg().arg("index").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(!e.status.success());
    assert!(
        err.contains("100 bytes") && err.contains("run shard"),
        "{err}"
    );
    // An input changed since planning is refused.
    write_input(&input, 1000, 4);
    let e = pcimg()
        .args(["convert", "-q", "--plan"])
        .arg(&p)
        .args(["--shard", "0/4"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(err.contains("changed since it was planned"), "{err}");
}

/// Whether python3 can import dask.distributed; under CI=true its absence fails.
fn have_dask() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import dask.distributed"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true and python3 cannot import dask.distributed (pip install \"dask[distributed]\")"
        );
        eprintln!("skipped: python3 cannot import dask.distributed");
    }
    ok
}

/// A shard killed with SIGKILL while it writes (its hidden staging folder
/// `.shard-I.tmp-*` is there, not after a guessed time) leaves that folder; the
/// next shard run removes it (its lock died with the shard), says so, and the
/// dataset is finished as if nothing had happened.
#[test]
fn a_killed_shard_leaves_nothing_the_next_run_trips_on() {
    let t = tempfile::tempdir().unwrap();
    let input = t.path().join("cloud.xyz");
    write_input(&input, 600_000, 4);
    let (p, out) = (t.path().join("plan.json"), t.path().join("out.pcimg"));
    plan(&input, &p, &out, 2);
    let staging = || {
        std::fs::read_dir(&out).ok().is_some_and(|d| {
            d.flatten().any(|e| {
                e.file_name()
                    .to_string_lossy()
                    .starts_with(".shard-00000.tmp-")
            })
        })
    };
    let mut child = pcimg()
        .args(["convert", "-q", "--plan"])
        .arg(&p)
        .args(["--shard", "0/2"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while !staging() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "shard 0 ended before it could be killed"
        );
        assert!(
            start.elapsed().as_secs() < 60,
            "shard 0 never began to write"
        );
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(staging(), "the killed shard left nothing to clean");
    // The other shard, run now, removes the dead one's folder.
    let o = pcimg()
        .args(["convert", "--plan"])
        .arg(&p)
        .args(["--shard", "1/2"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("left by a shard that was stopped"), "{err}");
    assert!(!staging());
    run(pcimg()
        .args(["convert", "-q", "--plan"])
        .arg(&p)
        .args(["--shard", "0/2"]));
    run(pcimg().arg("index").arg(&out));
    let hidden: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
    assert_eq!(digest(&out).points, 600_000);
}

#[test]
fn dask_driver_retries_a_killed_shard_and_equals_one_convert() {
    if !have_dask() {
        return;
    }
    let t = tempfile::tempdir().unwrap();
    let input = t.path().join("cloud.xyz");
    write_input(&input, 1_000_000, 5);
    let (p, out) = (t.path().join("plan.json"), t.path().join("out.pcimg"));
    plan(&input, &p, &out, 6);
    // The first attempt of shard 4 is killed (SIGKILL) once it has begun to
    // write (its staging folder is there), not after a guessed time: a shard
    // that ended before that marks the kill as missed.
    let marker = t.path().join("killed-once");
    let missed = t.path().join("kill-missed");
    let wrapper = t.path().join("pcimg-wrapper.sh");
    std::fs::write(
        &wrapper,
        format!(
            "#!/bin/sh\ncase \"$*\" in *'--shard 4/'*) if [ ! -e '{m}' ]; then touch '{m}'; \
             '{b}' \"$@\" & p=$!; \
             until ls -a '{o}' 2>/dev/null | grep -q '^\\.shard-00004\\.tmp'; do \
             kill -0 $p 2>/dev/null || {{ touch '{x}'; break; }}; sleep 0.01; done; \
             kill -9 $p; kill -9 $$; fi;; esac\nexec '{b}' \"$@\"\n",
            m = marker.display(),
            x = missed.display(),
            o = out.display(),
            b = env!("CARGO_BIN_EXE_pcimg")
        ),
    )
    .unwrap();
    let driver: PathBuf = [
        env!("CARGO_MANIFEST_DIR"),
        "examples/cluster/dask_driver.py",
    ]
    .iter()
    .collect();
    let said = run(Command::new("python3")
        .arg(&driver)
        .arg(&p)
        .args(["--workers", "2", "--pcimg"])
        .arg(format!("sh {}", wrapper.display())));
    assert!(marker.exists(), "the kill never happened");
    assert!(!missed.exists(), "shard 4 ended before it could be killed");
    assert!(said.contains("6 shards done"), "{said}");
    assert!(
        said.contains("receipts of 6 shard(s) match the plan"),
        "{said}"
    );
    let got = digest(&out);
    assert_eq!(got.points, 1_000_000);
    assert_eq!(got, single(&input, t.path()));
}
