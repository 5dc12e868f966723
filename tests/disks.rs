//! Full disks, killed runs and runs at the same time (issue 39). Every place
//! pcimg writes is tried on a small tmpfs that fills up, mounted in a private
//! mount namespace (`unshare`, `common::on_tmpfs`), so no mount outlives a test:
//! a one-part conversion, the spill files of a multi-part conversion, the
//! `$TMPDIR` copy of a conversion to S3, `pcimg index` writing the overview,
//! and the `--cache` of a remote view. Each failure names the file system and
//! leaves the input untouched and nothing half-written; the cache stops growing
//! and the view goes on. A conversion killed with SIGKILL (once its temporary
//! files exist) leaves nothing the next run trips on; two conversions to one
//! output: the second is refused, naming the first; readers opening a dataset
//! while its index is rewritten always see a whole index.

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn exe() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_pcimg"))
}

/// A synthetic LAS scan of `n` points.
fn synth(dir: &Path, name: &str, n: u64) -> PathBuf {
    let p = dir.join(name);
    let o = Command::new(exe())
        .args(["synth", "-n", &n.to_string(), "-o"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    p
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The message names the full file system at `mount`.
fn says_full(err: &str, mount: &Path) {
    assert!(err.contains("No space left on device"), "{err}");
    assert!(
        err.contains(&format!("the file system at {} is full", mount.display())),
        "{err}"
    );
}

/// An empty directory to mount a tmpfs on, inside the test's directory.
fn mount_dir(t: &Path) -> PathBuf {
    let m = t.join("small");
    std::fs::create_dir(&m).unwrap();
    m.canonicalize().unwrap()
}

/// `pcimg convert EXTRA -o MOUNT/OUT INPUT` of a synthetic scan of `points`
/// points onto a full 4 MB tmpfs: it fails saying the disk is full, leaves
/// nothing on it, and the input is unchanged. Its standard error (`None`
/// where no tmpfs can be mounted, outside CI).
fn convert_onto_a_full_disk(points: u64, out: &str, extra: &[&str]) -> Option<String> {
    if !common::tmpfs_available() {
        return None;
    }
    let t = tempfile::tempdir().unwrap();
    let input = synth(t.path(), "scan.las", points);
    let hash = common::file_hash(&input);
    let m = mount_dir(t.path());
    let out = m.join(out);
    let mut args: Vec<&OsStr> = std::iter::once("convert")
        .chain(extra.iter().copied())
        .chain(["-o"])
        .map(OsStr::new)
        .collect();
    args.extend([out.as_os_str(), input.as_os_str()]);
    let r = common::on_tmpfs(&m, "4m", "", exe(), &args, &[], "");
    assert!(!r.output.status.success());
    let err = stderr(&r.output);
    says_full(&err, &m);
    assert_eq!(r.after, Vec::<String>::new(), "left on the disk: {err}");
    assert_eq!(common::file_hash(&input), hash, "the input changed");
    Some(err)
}

#[test]
fn a_one_part_conversion_onto_a_full_disk_fails_cleanly() {
    let Some(err) = convert_onto_a_full_disk(300_000, "one.tif", &["--compression", "none"]) else {
        return;
    };
    assert!(err.contains("write failed"), "{err}");
    // Uncompressed, the part's size is known: the message says how much it needs.
    assert!(err.contains("needed"), "{err}");
    // The default codec's part of more points fails as cleanly.
    let Some(err) = convert_onto_a_full_disk(1_000_000, "one.tif", &[]) else {
        return;
    };
    assert!(err.contains("write failed"), "{err}");
}

#[test]
fn the_spill_files_of_a_multi_part_conversion_on_a_full_disk() {
    // A small budget: several parts, their points spilled beside the output
    // (the disk that fills up) before any part is written.
    let Some(err) = convert_onto_a_full_disk(1_000_000, "many.pcimg", &["--memory", "1MiB"]) else {
        return;
    };
    assert!(err.contains("spatial regions"), "not several parts: {err}");
    assert!(err.contains("temporary file"), "{err}");
    assert!(err.contains("pcimg-spill"), "{err}");
    // The room the spill files need: a million records of at least x, y, z
    // as 32-bit floats.
    let needed = err
        .split("; about ")
        .nth(1)
        .and_then(|r| r.split(" needed)").next())
        .unwrap_or_else(|| panic!("no space needed in: {err}"));
    let mib: f64 = needed
        .strip_suffix(" MiB")
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{needed}: not MiB"));
    assert!((11.0..200.0).contains(&mib), "{needed}");
}

#[test]
fn pcimg_index_on_a_full_disk_keeps_the_old_index_and_overview() {
    if !common::tmpfs_available() {
        return;
    }
    let t = tempfile::tempdir().unwrap();
    let input = synth(t.path(), "scan.las", 600_000);
    let ds = t.path().join("ds.pcimg");
    let o = Command::new(exe())
        .args(["convert", "-q", "--memory", "1MiB", "-o"])
        .arg(&ds)
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(ds.join("overview").is_dir(), "no overview to rebuild");
    // Room for the dataset and 1 MiB more.
    let kib = tree_bytes(&ds) / 1024 + 1024;
    let m = mount_dir(t.path());
    let copy = m.join("ds.pcimg");
    // The dataset copied onto the tmpfs, then the disk filled but for 64 KiB:
    // the temporary overview folder can be made, not a node (a tile is 256
    // KiB a band).
    let setup = format!(
        "cp -r '{}' \"$T/\" || exit 98\n\
         dd if=/dev/zero of=\"$T/filler\" bs=64k 2>/dev/null\n\
         truncate -s -64K \"$T/filler\" || exit 98",
        ds.display()
    );
    let r = common::on_tmpfs(
        &m,
        &format!("{kib}k"),
        &setup,
        exe(),
        &[OsStr::new("index"), copy.as_os_str()],
        &[],
        &format!(
            "'{}' info \"$T/ds.pcimg\" || echo INFO-FAILED",
            exe().display()
        ),
    );
    assert_ne!(r.output.status.code(), Some(98), "{}", stderr(&r.output));
    assert!(!r.output.status.success(), "index succeeded on a full disk");
    let err = stderr(&r.output);
    says_full(&err, &m);
    assert!(err.contains("node-"), "not the overview's nodes: {err}");
    // Nothing added or taken: the old index and overview serve on.
    assert_eq!(r.after, r.before, "{err}");
    assert!(r.before.iter().any(|f| f == "ds.pcimg/pcimg-index.json"));
    let said = String::from_utf8_lossy(&r.output.stdout);
    assert!(!said.contains("INFO-FAILED"), "{said}\n{err}");
    assert!(said.contains("600,000"), "{said}");
}

/// Bytes of the files under `dir`.
fn tree_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| match e.file_type().unwrap().is_dir() {
            true => tree_bytes(&e.path()),
            false => e.metadata().unwrap().len(),
        })
        .sum()
}

#[test]
fn a_conversion_to_s3_with_a_full_tmpdir_uploads_nothing() {
    if !common::tmpfs_available() {
        return;
    }
    let Some(w) = common::servers::Weed::start() else {
        return;
    };
    let t = tempfile::tempdir().unwrap();
    let input = synth(t.path(), "scan.las", 1_000_000);
    let hash = common::file_hash(&input);
    let m = mount_dir(t.path());
    let url = format!("s3://{}/full/scan.pcimg", common::servers::WEED_BUCKET);
    let env = w.env();
    let mut envs: Vec<(&str, &OsStr)> = env.iter().map(|(k, v)| (*k, OsStr::new(v))).collect();
    envs.push(("TMPDIR", m.as_os_str()));
    let r = common::on_tmpfs(
        &m,
        // (Its parts are compressed: a small disk.)
        "1m",
        "",
        exe(),
        &[
            OsStr::new("convert"),
            OsStr::new("-o"),
            OsStr::new(&url),
            input.as_os_str(),
        ],
        &envs,
        "",
    );
    assert!(!r.output.status.success());
    let err = stderr(&r.output);
    says_full(&err, &m);
    assert_eq!(r.after, Vec::<String>::new(), "left in $TMPDIR: {err}");
    assert_eq!(
        w.list("full").unwrap(),
        Vec::<(String, u64)>::new(),
        "{err}"
    );
    assert_eq!(common::file_hash(&input), hash, "the input changed");
}

#[test]
fn a_full_cache_disk_stops_the_cache_not_the_view() {
    if !common::tmpfs_available() {
        return;
    }
    let Some(w) = common::servers::Weed::start() else {
        return;
    };
    let t = tempfile::tempdir().unwrap();
    let input = synth(t.path(), "scan.las", 1_000_000);
    let url = format!("s3://{}/cached/scan.pcimg", common::servers::WEED_BUCKET);
    let o = Command::new(exe())
        .args(["convert", "-q", "--memory", "1MiB", "-o", &url])
        .arg(&input)
        .envs(w.env())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let render = |png: &Path, extra: &[&OsStr]| -> Vec<std::ffi::OsString> {
        let mut a: Vec<std::ffi::OsString> = [
            "render",
            &url,
            "--renderer",
            "cpu",
            "--width",
            "320",
            "--height",
            "200",
            // The finest level: every point, far more than the cache's disk.
            "--lod",
            "0",
            "-o",
        ]
        .iter()
        .map(|s| s.into())
        .collect();
        a.push(png.into());
        a.extend(extra.iter().map(|s| s.into()));
        a
    };
    let plain = t.path().join("plain.png");
    let o = Command::new(exe())
        .args(render(&plain, &[]))
        .envs(w.env())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let m = mount_dir(t.path());
    let cache = m.join("cache");
    let cached = t.path().join("cached.png");
    let args = render(
        &cached,
        &[
            OsStr::new("--cache"),
            cache.as_os_str(),
            OsStr::new("--net-stats"),
        ],
    );
    let args: Vec<&OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    let env = w.env();
    let envs: Vec<(&str, &OsStr)> = env.iter().map(|(k, v)| (*k, OsStr::new(v))).collect();
    let r = common::on_tmpfs(&m, "1m", "", exe(), &args, &envs, "");
    let err = stderr(&r.output);
    assert!(r.output.status.success(), "{err}");
    assert!(err.contains("disk cache:"), "{err}");
    assert!(err.contains("the cache stopped growing"), "{err}");
    assert!(
        err.contains(&format!("the file system at {} is full", m.display())),
        "{err}"
    );
    // The view is the one drawn without a cache.
    assert_eq!(
        common::file_hash(&cached),
        common::file_hash(&plain),
        "the picture differs"
    );
    // No temporary cache file was left.
    assert!(
        r.after.iter().all(|f| !f.contains(".tmp-")),
        "{:?}",
        r.after
    );
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Starts `pcimg args`, waits until `ready` holds (polling every
/// millisecond, 60 s at most) and kills the process with SIGKILL. Fails when
/// the process ended first (the kill would have missed).
fn kill_when(args: &[&OsStr], ready: impl Fn() -> bool) {
    let mut child = Command::new(exe())
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !ready() {
        if let Some(st) = child.try_wait().unwrap() {
            panic!("the run ended ({st}) before it could be killed");
        }
        assert!(start.elapsed() < Duration::from_secs(60), "never ready");
        std::thread::sleep(Duration::from_millis(1));
    }
    child.kill().unwrap();
    child.wait().unwrap();
}

fn has_entry(dir: &Path, prefix: &str, tag: &str) -> bool {
    names(dir)
        .iter()
        .any(|n| n.starts_with(prefix) && n.contains(tag))
}

#[test]
fn a_killed_conversion_leaves_nothing_the_next_run_trips_on() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let input = synth(d, "scan.las", 1_000_000);
    // A multi-part conversion killed while it spills; a single part while its
    // temporary file is written.
    for (out, tag, extra) in [
        (
            "many.pcimg",
            ".many.pcimg.pcimg-spill-",
            &["--memory", "1MiB"][..],
        ),
        ("one.tif", ".tmp", &[][..]),
    ] {
        let out = d.join(out);
        let mut args: Vec<&OsStr> = vec![OsStr::new("convert")];
        args.extend(extra.iter().map(OsStr::new));
        args.extend([OsStr::new("-o"), out.as_os_str(), input.as_os_str()]);
        let prefix = format!(".{}", out.file_name().unwrap().to_string_lossy());
        kill_when(&args, || has_entry(d, &prefix, tag));
        let left = names(d);
        assert!(
            left.iter()
                .any(|n| n.starts_with(&prefix) && n.contains(tag)),
            "{left:?}"
        );
        // The same command again: it removes what the killed run left, says
        // so, and succeeds.
        let o = Command::new(exe()).args(&args).output().unwrap();
        let err = stderr(&o);
        assert!(o.status.success(), "{err}");
        assert!(err.contains("left by a run that was stopped"), "{err}");
        assert_eq!(
            pcimg::store::Dataset::open(&out).unwrap().points(),
            1_000_000
        );
    }
    assert_eq!(names(d), ["many.pcimg", "one.tif", "scan.las"]);
}

#[test]
fn a_killed_index_leaves_nothing_the_next_run_trips_on() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let input = synth(d, "scan.las", 1_000_000);
    let ds = d.join("ds.pcimg");
    let o = Command::new(exe())
        .args(["convert", "-q", "--memory", "1MiB", "-o"])
        .arg(&ds)
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let before = names(&ds);
    kill_when(&[OsStr::new("index"), ds.as_os_str()], || {
        has_entry(&ds, ".overview-tmp-", "")
    });
    assert!(has_entry(&ds, ".overview-tmp-", ""), "{:?}", names(&ds));
    // The dataset still opens meanwhile (the old index and overview).
    pcimg::store::Dataset::open(&ds).unwrap();
    // `convert --force` onto it would have refused a folder of unknown files;
    // `index` again removes the leftovers.
    let o = Command::new(exe()).arg("index").arg(&ds).output().unwrap();
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("left by a run that was stopped"), "{err}");
    assert_eq!(names(&ds), before);
    let o = Command::new(exe())
        .args(["convert", "-q", "--force", "--memory", "1MiB", "-o"])
        .arg(&ds)
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn two_conversions_to_one_output_one_is_refused() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let input = synth(d, "scan.las", 1_000_000);
    let out = d.join("both.pcimg");
    let args = |out: &Path| -> Vec<std::ffi::OsString> {
        vec![
            "convert".into(),
            "--memory".into(),
            "1MiB".into(),
            "-o".into(),
            out.into(),
            input.clone().into(),
        ]
    };
    let mut first = Command::new(exe())
        .args(args(&out))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Ready: the first run holds the lock once it wrote its process id there.
    let lock = d.join(".both.pcimg.pcimg-lock");
    let pid = first.id().to_string();
    let start = Instant::now();
    while std::fs::read_to_string(&lock)
        .ok()
        .map(|s| s.trim().to_string())
        != Some(pid.clone())
    {
        assert!(
            first.try_wait().unwrap().is_none(),
            "the first run ended early"
        );
        assert!(start.elapsed() < Duration::from_secs(60), "no lock taken");
        std::thread::sleep(Duration::from_millis(1));
    }
    let second = Command::new(exe()).args(args(&out)).output().unwrap();
    let err = stderr(&second);
    assert!(!second.status.success(), "both ran");
    assert!(err.contains("another pcimg run is writing it"), "{err}");
    assert!(err.contains(&format!("process {pid}")), "{err}");
    // The first is not disturbed; the lock goes with it.
    let st = first.wait_with_output().unwrap();
    assert!(st.status.success(), "{}", stderr(&st));
    assert_eq!(
        pcimg::store::Dataset::open(&out).unwrap().points(),
        1_000_000
    );
    assert_eq!(names(d), ["both.pcimg", "scan.las"]);
    // A lock whose holder was killed does not block: the next run takes it.
    let out2 = d.join("again.pcimg");
    let lock2 = d.join(".again.pcimg.pcimg-lock");
    let a2 = args(&out2);
    let a2: Vec<&OsStr> = a2.iter().map(|a| a.as_os_str()).collect();
    kill_when(&a2, || lock2.exists());
    assert!(lock2.exists());
    let o = Command::new(exe()).args(&a2).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(names(d), ["again.pcimg", "both.pcimg", "scan.las"]);
}

#[test]
fn readers_see_the_old_or_the_new_index_never_a_torn_one() {
    use pcimg::store::dataset::overview::{IndexOptions, build_index};
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let input = synth(d, "scan.las", 1_000_000);
    let ds = d.join("ds.pcimg");
    let o = Command::new(exe())
        .args(["convert", "-q", "--memory", "1MiB", "-o"])
        .arg(&ds)
        .arg(&input)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let first = pcimg::store::Dataset::open(&ds).unwrap();
    let nodes_of = |d: &pcimg::store::Dataset| d.node_count();
    assert!(first.part_count() > 1 && nodes_of(&first) > 0);
    let (parts, nodes) = (first.part_count(), nodes_of(&first));
    let done = AtomicBool::new(false);
    let (reads, rewrites) = (AtomicUsize::new(0), AtomicUsize::new(0));
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| {
                while !done.load(Ordering::Relaxed) {
                    let got = pcimg::store::Dataset::open(&ds);
                    let got = got.unwrap_or_else(|e| panic!("a reader failed: {e}"));
                    // Read from an index (not by opening every part), whole.
                    assert!(got.index_bytes.is_some(), "no index seen");
                    assert_eq!((got.part_count(), nodes_of(&got)), (parts, nodes));
                    assert_eq!(got.points(), 1_000_000);
                    reads.fetch_add(1, Ordering::Relaxed);
                }
            });
        }
        for _ in 0..20 {
            build_index(&ds, &IndexOptions::default(), &|_| {}).unwrap();
            rewrites.fetch_add(1, Ordering::Relaxed);
        }
        done.store(true, Ordering::Relaxed);
    });
    let r = reads.load(Ordering::Relaxed);
    assert!(r >= 20, "only {r} reads during the rewrites");
    // The nodes of the index before the last stay (for readers holding
    // it); older ones were removed as each new index took over.
    let overview = names(&ds.join("overview"));
    assert_eq!(overview.len(), 2 * nodes, "{overview:?}");

    // A reader that opened the dataset before a rebuild reads every node
    // of its own index after it (its nodes are not opened before).
    let held = pcimg::store::Dataset::open(&ds).unwrap();
    build_index(&ds, &IndexOptions::default(), &|_| {}).unwrap();
    common::fuzz::fast::read_dataset(&held)
        .unwrap_or_else(|e| panic!("a reader holding the old index: {e}"));
    assert_eq!(names(&ds.join("overview")).len(), 2 * nodes);
}
