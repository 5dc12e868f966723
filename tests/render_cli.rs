//! `pcimg render` and `pcimg preview` as a user runs them: golden images of a real
//! sample (looked at by a person: tests/golden/*.png), camera JSON round trip, and
//! clear refusals.

use std::path::{Path, PathBuf};
use std::process::Command;

fn exe() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pcimg"));
    c.env("NODEVICE_SELECT", "1");
    c
}

fn autzen(dir: &Path) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/autzen_trim.laz");
    let out = dir.join("autzen.tif");
    let o = exe()
        .args(["convert", "-q", "-o"])
        .arg(&out)
        .arg(&src)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn png(path: &Path) -> image::RgbaImage {
    image::open(path).unwrap().to_rgba8()
}

/// Share of pixels within 2 levels per channel.
fn agreement(a: &image::RgbaImage, b: &image::RgbaImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let same = a
        .pixels()
        .zip(b.pixels())
        .filter(|(p, q)| (0..3).all(|c| (p[c] as i32 - q[c] as i32).abs() <= 2))
        .count();
    same as f64 / (a.width() * a.height()) as f64
}

#[test]
fn golden_images_of_autzen() {
    let dir = tempfile::tempdir().unwrap();
    let ds = autzen(dir.path());
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    for (name, extra) in [
        ("autzen_rgb_cpu.png", vec!["--color", "rgb"]),
        (
            "autzen_intensity_edl_cpu.png",
            vec!["--color", "intensity", "--edl", "--point-size", "2"],
        ),
    ] {
        let out = dir.path().join(name);
        let o = exe()
            .arg("render")
            .arg(&ds)
            .args([
                "--renderer",
                "cpu",
                "--width",
                "480",
                "--height",
                "270",
                "--view",
                "30,-45",
                "-o",
            ])
            .arg(&out)
            .args(&extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report = String::from_utf8_lossy(&o.stderr);
        assert!(report.contains("110,000 points"), "{report}");
        let (got, want) = (png(&out), png(&golden.join(name)));
        let share = agreement(&got, &want);
        assert!(
            share >= 0.99,
            "{name}: only {:.2}% of pixels match the golden image",
            share * 100.0
        );
        // Not a blank frame: the cloud covers a good part of the view.
        let lit = got
            .pixels()
            .filter(|p| p[0] as u32 + p[1] as u32 + p[2] as u32 > 30)
            .count();
        assert!(lit > 480 * 270 / 20, "{name}: {lit} lit pixels");
    }
}

#[test]
fn camera_json_round_trip_and_levels() {
    let dir = tempfile::tempdir().unwrap();
    let ds = autzen(dir.path());
    let a = dir.path().join("a.png");
    let o = exe()
        .arg("render")
        .arg(&ds)
        .args([
            "--renderer",
            "cpu",
            "--width",
            "200",
            "--height",
            "120",
            "--view",
            "10,-60",
            "--print-camera",
            "-o",
        ])
        .arg(&a)
        .output()
        .unwrap();
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    let json = err
        .lines()
        .find(|l| l.starts_with('{'))
        .expect("camera JSON printed");
    let b = dir.path().join("b.png");
    let o = exe()
        .arg("render")
        .arg(&ds)
        .args([
            "--renderer",
            "cpu",
            "--width",
            "200",
            "--height",
            "120",
            "--camera",
            json,
            "-o",
        ])
        .arg(&b)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        png(&a).as_raw(),
        png(&b).as_raw(),
        "the same camera gives the same frame"
    );
    // A pinned coarser level draws fewer points.
    let o = exe()
        .arg("render")
        .arg(&ds)
        .args(["--renderer", "cpu", "--lod", "1", "-o"])
        .arg(dir.path().join("c.png"))
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("27,500 points"));
}

#[test]
fn a_closed_stdout_ends_info_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let ds = autzen(dir.path());
    // A pipe whose reading end is closed before pcimg starts: its first write
    // fails, however fast it runs. (Closing the end after the spawn raced with
    // pcimg writing all of its output into the pipe's buffer first.)
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = exe()
        .args(["info", "--tiles", "--json"])
        .arg(&ds)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(141), "{e}");
    assert!(e.is_empty(), "{e}");
}

#[test]
fn refusals_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let ds = autzen(dir.path());
    // preview needs a terminal; the test's stdout is a pipe.
    let o = exe().arg("preview").arg(&ds).output().unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("not a terminal") && e.contains("pcimg render"),
        "{e}"
    );
    // A bad --lod value and a bad colour are named.
    let o = exe()
        .arg("render")
        .arg(&ds)
        .args(["--lod", "sideways", "-o", "x.png"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("sideways"));
    let o = exe()
        .arg("render")
        .arg(&ds)
        .args(["--color", "plaid", "-o", "x.png"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("plaid"));
    // A level the dataset does not have, a misspelt camera field, an output
    // that is not a PNG and a zero budget: each refused before anything is
    // written, naming what is wrong.
    let refused = |args: &[&str], says: &[&str]| {
        let o = exe().arg("render").arg(&ds).args(args).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        for s in says {
            assert!(e.contains(s), "{args:?}: {e}");
        }
    };
    let out = dir.path().join("x.png");
    let out = out.to_str().unwrap();
    refused(
        &["--lod", "9", "-o", out],
        &["--lod 9", "levels 0 (finest) to 1"],
    );
    refused(
        &["--camera", r#"{"yaww": 1}"#, "-o", out],
        &["unknown field 'yaww'"],
    );
    refused(&["--budget", "0", "-o", out], &["--budget"]);
    let jpg = dir.path().join("x.jpg");
    refused(&["-o", jpg.to_str().unwrap()], &["PNG only"]);
    assert!(!jpg.exists() && !Path::new(out).exists());
}
