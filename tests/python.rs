//! The Python package (`python/`, issue 41): its pytest suite
//! (`python/tests/`) against laspy reading the original LAZ, on
//! the fixture converted by this build's binary, locally and over
//! `python3 -m http.server`; and on a synthetic scan converted into several
//! parts with an overview.
//!
//! The package is installed with `pip install ./python` (`.ci/run` does it).
//! With CI=true a python3 without `pcimg`, laspy or pytest is a failure, else
//! a skip that says how to install them.

mod common;
use common::cli::{convert, ok, pcimg};
use common::http::HttpServer;
use std::path::Path;
use std::process::Command;

/// The python3 with the package, laspy and pytest (`None` outside CI when
/// there is none).
fn python() -> Option<&'static str> {
    let py = common::python_with("pcimg, laspy, lazrs, numpy, pytest");
    if py.is_none() {
        eprintln!("note: install the package with `python3 -m pip install ./python pytest`");
    }
    py
}

/// Runs the pytest suite with `env`; its output on failure.
fn pytest(py: &str, env: &[(&str, &Path)], url: Option<&str>, file: &str) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut c = Command::new(py);
    c.args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg(root.join("python/tests").join(file))
        // Not the source folder: the installed package, with its native module.
        .current_dir(std::env::temp_dir());
    for (k, v) in env {
        c.env(k, v);
    }
    if let Some(u) = url {
        c.env("PCIMG_TEST_URL", u);
    }
    let o = c.output().unwrap();
    let said = ok(&o, "pytest python/tests");
    eprintln!("{said}");
    assert!(
        !said.contains(" skipped"),
        "a pytest test was skipped:\n{said}"
    );
}

#[test]
fn the_python_package_reads_what_laspy_reads_locally_and_over_http() {
    let Some(py) = python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let laz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/autzen_trim.laz");
    let ds = dir.path().join("autzen.pcimg");
    convert(&laz, &ds, &[]);
    let Some(server) = HttpServer::start(dir.path()) else {
        return;
    };
    let url = server.url("autzen.pcimg");
    pytest(
        py,
        &[("PCIMG_TEST_LAZ", &laz), ("PCIMG_TEST_DATASET", &ds)],
        Some(&url),
        "test_pcimg.py",
    );
}

#[test]
fn the_python_package_reads_a_dataset_of_many_parts_as_one() {
    let Some(py) = python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // A synthetic scan, kept as LAS for laspy, converted under a small budget.
    let las = dir.path().join("scan.las");
    ok(
        &pcimg()
            .args(["synth", "-n", "300000", "-o"])
            .arg(&las)
            .output()
            .unwrap(),
        "synth",
    );
    let ds = dir.path().join("scan.pcimg");
    convert(&las, &ds, &["--memory", "1MiB"]);
    pytest(
        py,
        &[
            ("PCIMG_TEST_PARTS_LAS", &las),
            ("PCIMG_TEST_PARTS_DATASET", &ds),
        ],
        None,
        "test_parts.py",
    );
}
