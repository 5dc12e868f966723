//! Bad networks (issue 39): a fault-injecting proxy (`common/proxy.rs`) in
//! front of `python3 -m http.server` or SeaweedFS (`weed mini`) adds latency,
//! resets connections, answers 500 and 503 SlowDown, cuts bodies short and
//! stalls, by a schedule each test sets. `info` and `render` through a fault
//! that passes succeed after retries, fetch again (the proxy counts it) and
//! give the result a healthy server gives; through a fault that persists they
//! fail within `--timeout` (plus one stalled try) with an error naming the
//! URL, the HTTP status or the network condition, and `--timeout`. A body cut
//! short is never cached: on disk (`--cache`) a later healthy run is right.
//! `convert -o s3://` through upload faults that pass completes; through one
//! that persists it fails, removes what it uploaded (the bucket is listed
//! behind the proxy's back) and says what it removed. With CI=true a missing
//! python3 or weed is a failure, else a skip. Small `--timeout` values keep
//! the whole file to seconds.

mod common;

use common::cli::{err, info_json, local_files, ok, pcimg};

use common::proxy::{Fault, Proxy, Rule};
use common::servers::{HttpServer, WEED_BUCKET, Weed};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/autzen_trim.laz")
}

/// The fixture converted into `dir/autzen.pcimg` (zstd, a 1 MiB budget).
fn convert(dir: &Path) -> PathBuf {
    let out = dir.join("autzen.pcimg");
    let o = pcimg()
        .args(["convert", "-q", "--memory", "1MiB", "--compression", "zstd"])
        .arg(fixture())
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    ok(&o, "convert");
    out
}

fn render_args(src: &str, png: &Path, timeout: &str) -> Vec<String> {
    let mut v: Vec<String> = [
        "render",
        src,
        "--renderer",
        "cpu",
        "--width",
        "240",
        "--height",
        "160",
        "--timeout",
        timeout,
        "-o",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    v.push(png.to_str().unwrap().to_string());
    v
}

/// Whether every request in `log` that met a fault was made again later and
/// passed.
fn refetched(log: &[common::proxy::Seen]) -> bool {
    log.iter().enumerate().all(|(i, s)| {
        s.fault == Fault::Pass
            || log[i + 1..]
                .iter()
                .any(|t| t.line == s.line && t.fault == Fault::Pass)
    })
}

/// The faults, each with words its persistent failure must be told in.
fn faults() -> Vec<(Fault, &'static [&'static str])> {
    vec![
        (Fault::Reset, &["the connection was cut"]),
        (Fault::Status500, &["HTTP 500 Internal Server Error"]),
        (
            Fault::SlowDown,
            &["HTTP 503 Service Unavailable", "SlowDown"],
        ),
        (Fault::Short(100), &["the connection was cut"]),
        (Fault::Stall, &["no answer in time (timed out)"]),
    ]
}

/// Over plain HTTP: every fault that passes after two requests is retried
/// through, and `render` and `info` give what they give without it.
#[test]
fn reads_through_faults_that_pass_are_retried_to_the_same_result() {
    let dir = tempfile::tempdir().unwrap();
    convert(dir.path());
    let Some(server) = HttpServer::start(dir.path()) else {
        return;
    };
    let proxy = Proxy::start(server.addr());
    let url = format!("{}/autzen.pcimg", proxy.url());
    let reference = dir.path().join("healthy.png");
    ok(
        &pcimg()
            .args(render_args(&url, &reference, "4s"))
            .output()
            .unwrap(),
        "render through a healthy proxy",
    );
    let reference = std::fs::read(&reference).unwrap();
    let healthy_parts = proxy.count(".tif");
    assert!(healthy_parts > 0, "{:?}", proxy.log());
    let info = info_json(&ok(
        &pcimg()
            .args(["info", "--json", "--timeout", "4s", &url])
            .output()
            .unwrap(),
        "info through a healthy proxy",
    ));
    let healthy_index = proxy.count("pcimg-index.json") - 1;

    let mut all = faults();
    all.insert(0, (Fault::Delay(Duration::from_millis(300)), &[]));
    for (fault, _) in all {
        // The parts' first two requests.
        proxy.reset_counters();
        proxy.set(vec![Rule::new(fault).matching(".tif").times(2)]);
        let png = dir.path().join("faulty.png");
        let start = Instant::now();
        let o = pcimg()
            .args(render_args(&url, &png, "4s"))
            .output()
            .unwrap();
        ok(&o, &format!("render through {fault:?} twice"));
        let spent = start.elapsed();
        assert!(
            std::fs::read(&png).unwrap() == reference,
            "{fault:?}: the render differs from the healthy one"
        );
        assert_eq!(proxy.faults(), 2, "{fault:?}: {:?}", proxy.log());
        if let Fault::Delay(d) = fault {
            assert!(spent >= d, "{fault:?}: {spent:?}");
            assert_eq!(proxy.count(".tif"), healthy_parts, "{:?}", proxy.log());
        } else {
            // Every request the fault spoilt was made again and answered (a
            // retry may fetch more than the spoilt range, so the count of
            // requests need not grow).
            assert!(
                refetched(&proxy.log()),
                "{fault:?}: nothing fetched again: {:?}",
                proxy.log()
            );
        }
        // The index's first two requests.
        proxy.reset_counters();
        proxy.set(vec![Rule::new(fault).matching("pcimg-index.json").times(2)]);
        let o = pcimg()
            .args(["info", "--json", "--timeout", "4s", &url])
            .output()
            .unwrap();
        assert_eq!(
            info_json(&ok(&o, &format!("info through {fault:?} twice"))),
            info,
            "{fault:?}"
        );
        if !matches!(fault, Fault::Delay(_)) {
            assert_eq!(
                proxy.count("pcimg-index.json"),
                healthy_index + 2,
                "{fault:?}: {:?}",
                proxy.log()
            );
        }
    }
}

/// Over plain HTTP: a fault that persists fails `info` (the index) and
/// `render` (a part) within the time limit, naming the URL, the status or
/// condition, and `--timeout`.
#[test]
fn reads_through_faults_that_persist_fail_within_the_limit_saying_why() {
    let dir = tempfile::tempdir().unwrap();
    convert(dir.path());
    let Some(server) = HttpServer::start(dir.path()) else {
        return;
    };
    let proxy = Proxy::start(server.addr());
    let url = format!("{}/autzen.pcimg", proxy.url());
    let limit = Duration::from_secs(1);
    for (fault, words) in faults() {
        proxy.reset_counters();
        proxy.set(vec![Rule::new(fault).matching("pcimg-index.json")]);
        let start = Instant::now();
        let o = pcimg()
            .args(["info", "--timeout", "1s", &url])
            .output()
            .unwrap();
        let spent = start.elapsed();
        let e = err(&o, &format!("info through {fault:?} for good"));
        let at = format!("pcimg: {url}/pcimg-index.json: ");
        assert!(e.starts_with(&at), "{fault:?}: {e}");
        for w in words {
            assert!(e.contains(w), "{fault:?}: no {w:?} in {e}");
        }
        assert!(
            e.contains("given up after") && e.contains("raise --timeout"),
            "{fault:?}: {e}"
        );
        assert!(
            proxy.count("pcimg-index.json") >= 2,
            "{fault:?}: not tried again: {:?}",
            proxy.log()
        );
        // The limit, one stalled try (a quarter of it) and the process's own
        // start and exit.
        assert!(
            spent >= limit / 2 && spent < limit + limit / 4 + Duration::from_secs(3),
            "{fault:?}: failed after {spent:?}"
        );
    }
    // A part cut short for good: `render` names the part's URL.
    proxy.reset_counters();
    proxy.set(vec![Rule::new(Fault::Short(100)).matching(".tif")]);
    let png = dir.path().join("never.png");
    let e = err(
        &pcimg()
            .args(render_args(&url, &png, "1s"))
            .output()
            .unwrap(),
        "render through a part cut short for good",
    );
    assert!(
        e.contains(&format!("{url}/")) && e.contains(".tif: the connection was cut"),
        "{e}"
    );
    assert!(e.contains("raise --timeout"), "{e}");
    assert!(!png.exists(), "a picture was written");
}

/// From S3 (answers with ETags: object_store resumes a body cut short, and the
/// disk cache keeps ranges): a body cut short for good is never cached, and a
/// later healthy run with the same `--cache` draws the healthy picture.
#[test]
fn s3_bodies_cut_short_are_resumed_and_never_cached() {
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let url = format!("s3://{WEED_BUCKET}/autzen.pcimg");
    let direct = weed.endpoint();
    ok(
        &weed
            .pcimg(
                &direct,
                &[
                    "convert",
                    "-q",
                    "--compression",
                    "zstd",
                    fixture().to_str().unwrap(),
                    "-o",
                    &url,
                ],
            )
            .output()
            .unwrap(),
        "convert -o s3://",
    );
    let proxy = Proxy::start(weed.addr());
    let through = proxy.url();
    let render = |png: &Path, timeout: &str, cache: Option<&Path>| {
        let mut args = render_args(&url, png, timeout);
        if let Some(c) = cache {
            args.extend(["--cache".to_string(), c.to_str().unwrap().to_string()]);
        }
        args.push("--net-stats".into());
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        weed.pcimg(&through, &args).output().unwrap()
    };
    let reference = dir.path().join("healthy.png");
    ok(
        &render(&reference, "4s", None),
        "render through a healthy proxy",
    );
    let reference = std::fs::read(&reference).unwrap();
    let healthy_parts = proxy.count(".tif");

    // Cut short twice: resumed, the same picture.
    proxy.reset_counters();
    proxy.set(vec![Rule::new(Fault::Short(500)).matching(".tif").times(2)]);
    let png = dir.path().join("resumed.png");
    ok(&render(&png, "4s", None), "render through two cut bodies");
    assert!(
        std::fs::read(&png).unwrap() == reference,
        "the render differs"
    );
    assert_eq!(proxy.faults(), 2);
    assert!(proxy.count(".tif") > healthy_parts, "{:?}", proxy.log());

    // Cut short for good, with a disk cache: fails, and nothing is cached.
    let cache = dir.path().join("cache");
    proxy.reset_counters();
    proxy.set(vec![Rule::new(Fault::Short(500)).matching(".tif")]);
    let png = dir.path().join("never.png");
    let e = err(
        &render(&png, "1s", Some(&cache)),
        "render through bodies cut short for good",
    );
    assert!(
        e.contains(&format!("{url}/")) && e.contains(".tif: the connection was cut"),
        "{e}"
    );
    let ranges = |dir: &Path| {
        std::fs::read_dir(dir)
            .map(|d| {
                d.filter(|e| {
                    e.as_ref()
                        .unwrap()
                        .path()
                        .extension()
                        .is_some_and(|x| x == "rng")
                })
                .count()
            })
            .unwrap_or(0)
    };
    assert_eq!(ranges(&cache), 0, "a range cut short was cached");

    // Healthy again, the same cache: the healthy picture, then from the disk.
    proxy.set(vec![]);
    let png = dir.path().join("after.png");
    ok(&render(&png, "4s", Some(&cache)), "render after the faults");
    assert!(
        std::fs::read(&png).unwrap() == reference,
        "the render differs"
    );
    assert!(ranges(&cache) > 0, "nothing cached from healthy answers");
    let o = render(&png, "4s", Some(&cache));
    let stats = String::from_utf8_lossy(&o.stderr).into_owned();
    ok(&o, "render from the disk cache");
    assert!(
        std::fs::read(&png).unwrap() == reference,
        "the render differs"
    );
    assert!(!stats.contains("disk cache: 0 hits"), "{stats}");
}

/// `convert -o s3://` through upload faults: those that pass are retried to
/// a complete dataset; one that persists removes what was uploaded, says
/// what, and leaves nothing under the prefix (nor in `$TMPDIR`).
#[test]
fn uploads_through_faults_complete_or_leave_nothing_and_say_so() {
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("local.pcimg");
    let args = ["convert", "--memory", "1MiB", "--compression", "zstd"];
    let mut c = pcimg();
    c.args(args).arg(fixture()).arg("-o").arg(&local);
    ok(&c.output().unwrap(), "convert locally");
    let want = local_files(&local);
    assert!(want.len() >= 2, "a part and the index: {want:?}");
    let proxy = Proxy::start(weed.addr());
    let through = proxy.url();
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    let convert = |name: &str, timeout: &str| {
        let url = format!("s3://{WEED_BUCKET}/{name}");
        let input = fixture();
        let mut all: Vec<&str> = args.to_vec();
        // (Not -q: the removal is told in the notes.)
        all.extend([input.to_str().unwrap(), "-o", &url, "--timeout", timeout]);
        weed.pcimg(&through, &all)
            .env("TMPDIR", &tmp)
            .output()
            .unwrap()
    };

    for (i, fault) in [Fault::Status500, Fault::SlowDown, Fault::Reset]
        .into_iter()
        .enumerate()
    {
        proxy.reset_counters();
        let name = format!("up{i}.pcimg");
        // The dataset's objects (not the lock beside them).
        let puts = format!("PUT /{WEED_BUCKET}/{name}/");
        proxy.set(vec![Rule::new(fault).matching(&puts).times(2)]);
        ok(
            &convert(&name, "5s"),
            &format!("convert through {fault:?} twice"),
        );
        assert_eq!(proxy.faults(), 2, "{fault:?}: {:?}", proxy.log());
        // Every object once, and the two refused uploads again.
        assert_eq!(
            proxy.count(&puts),
            want.len() + 2,
            "{fault:?}: {:?}",
            proxy.log()
        );
        let got: Vec<(String, u64)> = weed
            .list(&name)
            .unwrap()
            .into_iter()
            .map(|(n, s)| (n.strip_prefix(&format!("{name}/")).unwrap().to_string(), s))
            .collect();
        // The index records the upload's ETags: its size differs.
        let strip = |v: &[(String, u64)]| -> Vec<(String, u64)> {
            v.iter()
                .filter(|(n, _)| n != "pcimg-index.json")
                .cloned()
                .collect()
        };
        assert_eq!(strip(&got), strip(&want), "{fault:?}");
        assert!(got.iter().any(|(n, _)| n == "pcimg-index.json"), "{got:?}");
    }

    // A fault that persists after the first upload.
    proxy.reset_counters();
    let puts = format!("PUT /{WEED_BUCKET}/cut.pcimg/");
    proxy.set(vec![Rule::new(Fault::Status500).matching(&puts).after(1)]);
    let start = Instant::now();
    let o = convert("cut.pcimg", "1s");
    let spent = start.elapsed();
    let e = err(&o, "convert through a persistent fault");
    let url = format!("s3://{WEED_BUCKET}/cut.pcimg");
    assert!(
        e.contains(&format!("{url}/")) && e.contains("HTTP 500 Internal Server Error"),
        "{e}"
    );
    assert!(
        e.contains("removed ") && e.contains(&format!("object(s) from {url}: ")),
        "{e}"
    );
    assert!(
        e.contains(&format!("nothing of this conversion is left at {url}")),
        "{e}"
    );
    assert!(spent < Duration::from_secs(30), "{spent:?}");
    assert!(
        proxy
            .log()
            .iter()
            .any(|r| r.line.starts_with(&puts) && r.fault == Fault::Pass),
        "no upload got through before the fault: {:?}",
        proxy.log()
    );
    assert_eq!(
        weed.list("cut.pcimg").unwrap(),
        vec![],
        "left in the bucket"
    );
    let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
    assert!(left.is_empty(), "left in TMPDIR: {left:?}");
}

/// A store of the test's SeaweedFS reached at `endpoint` (a proxy in front
/// of it), configured by the caller as a program would, not by `AWS_*`.
fn s3_remote(endpoint: &str, prefix: &str, timeout: Duration) -> pcimg::remote::Remote {
    use common::servers::{WEED_KEY, WEED_SECRET};
    pcimg::remote::Remote::open_configured(
        &format!("s3://{WEED_BUCKET}/{prefix}"),
        &pcimg::remote::Options { timeout },
        &[
            ("aws_endpoint", endpoint),
            ("aws_allow_http", "true"),
            ("aws_region", "us-east-1"),
            ("aws_access_key_id", WEED_KEY),
            ("aws_secret_access_key", WEED_SECRET),
        ],
    )
    .unwrap()
}

/// A file above the multipart threshold through faults on its parts and on
/// the completing request: each part is sent again by itself (the same part
/// number) until the upload completes, byte for byte; a part that keeps
/// failing aborts the upload within the time limit, names the part, and
/// leaves no object.
#[test]
fn large_uploads_retry_each_part_and_abort_when_one_keeps_failing() {
    use pcimg::remote::upload::{MULTIPART_ABOVE, Uploader};
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("big.bin");
    // Three parts (8 + 8 + 4 MiB) of bytes that differ everywhere.
    let size = MULTIPART_ABOVE as usize + (4 << 20);
    let mut rng = pcimg::synth::Rng::new(39);
    let data: Vec<u8> = (0..size).map(|_| rng.next_u64() as u8).collect();
    std::fs::write(&local, &data).unwrap();
    let proxy = Proxy::start(weed.addr());
    let upload = |prefix: &str, timeout: Duration| {
        let remote = Arc::new(s3_remote(&proxy.url(), prefix, timeout));
        let up = Uploader::new(remote, Arc::new(AtomicBool::new(false)));
        up.start(&local, "big.bin")
            .and_then(|()| up.wait())
            .map(|()| up.uploaded("big.bin"))
    };

    proxy.set(vec![
        Rule::new(Fault::Status500)
            .matching("partNumber=2")
            .times(2),
        Rule::new(Fault::Reset).matching("partNumber=3").times(1),
        Rule::new(Fault::SlowDown)
            .matching("POST ")
            .after(1)
            .times(1),
    ]);
    let got = upload("ok", Duration::from_secs(10)).expect("the upload through passing faults");
    assert_eq!(got.map(|g| g.0), Some(size as u64));
    assert_eq!(proxy.faults(), 4, "{:?}", proxy.log());
    // Parts 2 and 3 sent again, by the same part number.
    for (n, times) in [(1, 1), (2, 3), (3, 2)] {
        assert_eq!(
            proxy.count(&format!("partNumber={n}&")),
            times,
            "part {n}: {:?}",
            proxy.log()
        );
    }
    assert!(
        weed.get("ok/big.bin").unwrap() == data,
        "the object differs from the file"
    );

    proxy.reset_counters();
    proxy.set(vec![Rule::new(Fault::Status500).matching("partNumber=2")]);
    let start = Instant::now();
    let e = upload("cut", Duration::from_secs(2)).expect_err("a part that keeps failing");
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "{:?}",
        start.elapsed()
    );
    assert!(
        e.contains(&format!("s3://{WEED_BUCKET}/cut/big.bin"))
            && e.contains("part 2")
            && e.contains("HTTP 500"),
        "{e}"
    );
    // Aborted: the parts the server held are deleted, no object is made.
    assert!(
        proxy
            .log()
            .iter()
            .any(|r| r.line.starts_with("DELETE ") && r.line.contains("uploadId=")),
        "no abort: {:?}",
        proxy.log()
    );
    assert_eq!(weed.list("cut").unwrap(), vec![], "left in the bucket");
}

/// A part smaller than the first read (64 KiB) opened by its URL from a
/// server that honours Range: the first request asks no further than its
/// end (an answer shorter than asked was taken for a cut body and retried
/// until the time limit).
#[test]
fn a_small_part_opens_by_its_s3_url_without_retries() {
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let part = common::cli::tiny_part(dir.path());
    weed.put("small/t.tif", std::fs::read(&part).unwrap())
        .unwrap();
    let url = format!("s3://{WEED_BUCKET}/small/t.tif");
    let here = pcimg()
        .args(["info", "--json"])
        .arg(&part)
        .output()
        .unwrap();
    let there = weed
        .pcimg(
            &weed.endpoint(),
            &["info", "--json", "--net-stats", "--timeout", "20s", &url],
        )
        .output()
        .unwrap();
    assert_eq!(
        info_json(&ok(&here, "info")),
        info_json(&ok(&there, "info of a small part in S3"))
    );
    let stats = String::from_utf8_lossy(&there.stderr);
    assert!(stats.contains(", 0 failed"), "{stats}");
}

/// Two conversions to the same S3 prefix: the second is refused, naming the
/// first's process and the lock, while the first completes; a run killed
/// holding the lock leaves it, and the next run on this host takes it over
/// and says so (even with `-q`). The lock object sits beside the prefix and
/// is gone after each run.
#[test]
fn a_second_conversion_to_the_same_s3_prefix_is_refused_and_a_killed_ones_lock_taken_over() {
    let Some(weed) = Weed::start() else { return };
    let proxy = Proxy::start(weed.addr());
    let url = format!("s3://{WEED_BUCKET}/two.pcimg");
    let lock = ".two.pcimg.pcimg-lock";
    let input = fixture();
    let args = |extra: &[&'static str]| -> Vec<String> {
        let mut v: Vec<String> = ["convert", "--memory", "1MiB", "--compression", "zstd"]
            .iter()
            .chain(extra)
            .map(|s| s.to_string())
            .collect();
        v.extend([input.display().to_string(), "-o".into(), url.clone()]);
        v
    };
    let has_lock = || weed.list("").unwrap().iter().any(|(n, _)| n == lock);
    let wait_for_lock = |child: &mut std::process::Child| {
        let start = Instant::now();
        while !has_lock() {
            assert!(child.try_wait().unwrap().is_none(), "the first run ended");
            assert!(start.elapsed() < Duration::from_secs(60), "no lock in 60 s");
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    // The first run's part uploads are slowed down by the proxy.
    proxy.set(vec![
        Rule::new(Fault::Delay(Duration::from_millis(1500))).matching("/two.pcimg/"),
    ]);
    let slow = |extra: &[&'static str]| {
        let a = args(extra);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        weed.pcimg(&proxy.url(), &a)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let direct = |extra: &[&'static str]| {
        let a = args(extra);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        weed.pcimg(&weed.endpoint(), &a).output().unwrap()
    };

    let mut first = slow(&["--timeout", "60s"]);
    wait_for_lock(&mut first);
    let e = err(&direct(&[]), "a second conversion to the same prefix");
    assert!(
        e.contains(&format!(
            "{url}: another pcimg run is writing it (process {}",
            first.id()
        )) && e.contains(&format!("s3://{WEED_BUCKET}/{lock}")),
        "{e}"
    );
    let o = first.wait_with_output().unwrap();
    ok(&o, "the first conversion");
    assert!(!has_lock(), "the lock outlived its run");
    assert!(
        weed.list("two.pcimg/")
            .unwrap()
            .iter()
            .any(|(n, _)| n.ends_with("pcimg-index.json")),
        "the first run's dataset is incomplete"
    );

    // Killed holding the lock: the next run (quiet) takes it over.
    let mut killed = slow(&["--force", "--timeout", "60s"]);
    wait_for_lock(&mut killed);
    let pid = killed.id();
    killed.kill().unwrap();
    let _ = killed.wait();
    assert!(has_lock(), "a killed run's lock is left");
    let o = direct(&["--force", "-q"]);
    ok(&o, "a conversion after a killed one");
    let notes = String::from_utf8_lossy(&o.stderr);
    assert!(
        notes.contains(&format!(
            "took over the lock s3://{WEED_BUCKET}/{lock} of process {pid}, a run that was stopped"
        )),
        "{notes}"
    );
    assert!(!has_lock(), "the lock outlived its run");
}
