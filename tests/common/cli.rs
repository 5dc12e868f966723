//! Running the `pcimg` binary in a test and reading what it said: success
//! with its standard output, failure with its standard error, `info --json`
//! without the fields that say where a dataset is, and a dataset's files.

use std::path::Path;
use std::process::{Command, Output};

/// The `pcimg` binary, with no GPU adapter search.
pub fn pcimg() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
    c.env("NODEVICE_SELECT", "1");
    c
}

/// `pcimg convert -q EXTRA… INPUT -o OUT`, which must succeed.
pub fn convert(input: &Path, out: &Path, extra: &[&str]) {
    let o = pcimg()
        .args(["convert", "-q"])
        .args(extra)
        .arg(input)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap();
    ok(&o, "convert");
}

/// Its standard output; fails the test, showing both streams, if it failed.
pub fn ok(o: &Output, what: &str) -> String {
    assert!(
        o.status.success(),
        "{what} failed:\n{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Its standard error; fails the test, showing its output, if it succeeded.
pub fn err(o: &Output, what: &str) -> String {
    assert!(
        !o.status.success(),
        "{what} should have failed:\n{}",
        String::from_utf8_lossy(&o.stdout)
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `info --json` without the fields that name where the dataset is (`path`)
/// and the `also` ones, at every depth.
pub fn info_json_without(text: &str, also: &[&str]) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value, keys: &[&str]) {
        match v {
            serde_json::Value::Object(m) => {
                for k in keys {
                    m.remove(*k);
                }
                m.values_mut().for_each(|v| strip(v, keys));
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(|v| strip(v, keys)),
            _ => {}
        }
    }
    let keys: Vec<&str> = std::iter::once("path")
        .chain(also.iter().copied())
        .collect();
    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    strip(&mut v, &keys);
    v
}

/// `info --json` without the fields that name where the dataset is.
pub fn info_json(text: &str) -> serde_json::Value {
    info_json_without(text, &[])
}

/// Every file under `dir` with its `/`-separated name and size, sorted.
pub fn local_files(dir: &Path) -> Vec<(String, u64)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p
                    .strip_prefix(dir)
                    .unwrap()
                    .to_string_lossy()
                    .replace('\\', "/");
                out.push((rel, std::fs::metadata(&p).unwrap().len()));
            }
        }
    }
    out.sort();
    out
}

/// A part of three points converted into `dir/t.tif` (zstd): a file far
/// smaller than a remote part's first read (64 KiB).
pub fn tiny_part(dir: &Path) -> std::path::PathBuf {
    let xyz = dir.join("t.xyz");
    std::fs::write(&xyz, "0 0 0\n1 1 1\n2 0 1\n").unwrap();
    let part = dir.join("t.tif");
    let o = pcimg()
        .args(["convert", "-q", "--compression", "zstd"])
        .arg(&xyz)
        .arg("-o")
        .arg(&part)
        .output()
        .unwrap();
    ok(&o, "convert");
    let size = std::fs::metadata(&part).unwrap().len();
    assert!(
        size < 64 << 10,
        "{size} bytes: not smaller than the first read"
    );
    part
}
