//! Terminal detection against terminals: the real binary (`pcimg doctor --json`,
//! `inspect`, `preview`) on a pseudo-terminal whose other side plays each known
//! terminal's answers (from their documentation and source), a terminal that
//! answers nothing and one that answers late; real tmux 3.3a asked through
//! `tmux display` with a scripted outer terminal; real xterm `-ti vt340` under
//! Xvfb; screenshots of real kitty and xterm under Xvfb showing the inspector
//! (its picture, and the scale bar's label one text row high in text mode); and
//! the sixel the inspector sends while the crosshair moves (patches, never the
//! frame again). Each checks the protocol chosen, the time taken, that a key typed during
//! the probe is not lost, and that the terminal is left as it was found.

mod common;

use common::pty::{self, Pty};
use common::tmux::Tmux;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_pcimg")
}

/// A terminal's answers to XTVERSION, the kitty query, `CSI 16 t` and DA1.
struct Profile {
    name: &'static str,
    xtversion: Option<&'static str>,
    kitty: Option<&'static str>,
    cell: Option<&'static str>,
    da1: Option<&'static str>,
    delay: Duration,
    /// The protocol it must get (`serde` name of `Graphics`).
    expect: &'static str,
}

const fn p(
    name: &'static str,
    xtversion: Option<&'static str>,
    kitty: Option<&'static str>,
    da1: Option<&'static str>,
    expect: &'static str,
) -> Profile {
    Profile {
        name,
        xtversion,
        kitty,
        cell: Some("\x1b[6;20;10t"),
        da1,
        delay: Duration::ZERO,
        expect,
    }
}

const OK: Option<&str> = Some("\x1b_Gi=31;OK\x1b\\");

fn profiles() -> Vec<Profile> {
    vec![
        p(
            "kitty",
            Some("kitty(0.35.2)"),
            OK,
            Some("\x1b[?62;c"),
            "Kitty",
        ),
        p(
            "Ghostty",
            Some("ghostty 1.1.3"),
            OK,
            Some("\x1b[?62;22c"),
            "Kitty",
        ),
        p(
            "Rio",
            Some("Rio 0.2.10"),
            OK,
            Some("\x1b[?62;4;22c"),
            "Kitty",
        ),
        // WezTerm answers the kitty query OK but draws no placeholders: by name.
        p(
            "WezTerm",
            Some("WezTerm 20240203-110809-5046fc22"),
            OK,
            Some("\x1b[?65;4;6;18;22c"),
            "Iterm2",
        ),
        p(
            "iTerm2",
            Some("iTerm2 3.5.0"),
            None,
            Some("\x1b[?62;4c"),
            "Iterm2",
        ),
        p(
            "foot",
            Some("foot(1.16.2)"),
            None,
            Some("\x1b[?62;4;22;28c"),
            "Sixel",
        ),
        // Konsole also answers OK to kitty, without placeholders: by name, sixel.
        p(
            "Konsole",
            Some("Konsole 24.02.1"),
            OK,
            Some("\x1b[?62;4;22c"),
            "Sixel",
        ),
        Profile {
            cell: None,
            ..p(
                "xterm -ti vt340",
                Some("XTerm(379)"),
                None,
                Some("\x1b[?63;1;2;4;6;9;15;16;22;28c"),
                "Sixel",
            )
        },
        Profile {
            cell: None,
            ..p(
                "xterm",
                Some("XTerm(379)"),
                None,
                Some("\x1b[?64;1;2;6;9;15;16;17;18;21;22;28c"),
                "Halfblocks",
            )
        },
        p(
            "VS Code (images on)",
            Some("xterm.js(5.5.0)"),
            None,
            Some("\x1b[?62;4;9;22c"),
            "Sixel",
        ),
        p(
            "Windows Terminal",
            None,
            None,
            Some("\x1b[?61;4;6;7;14;21;22;23;24;28;32;42c"),
            "Sixel",
        ),
        Profile {
            cell: None,
            ..p("answers nothing", None, None, None, "Halfblocks")
        },
        Profile {
            delay: Duration::from_millis(300),
            ..p(
                "kitty over a slow link (300 ms)",
                Some("kitty(0.35.2)"),
                OK,
                Some("\x1b[?62;c"),
                "Kitty",
            )
        },
    ]
}

/// Plays `t` for `cmd` on a new pty: waits for the queries, types `key`, answers
/// after the profile's delay. Returns the pty after the program ended.
fn play(t: &Profile, cmd: &mut Command, key: &[u8], px: (u16, u16)) -> (Pty, Duration) {
    let mut term = Pty::spawn(cmd, (120, 40), px);
    assert!(
        term.read_until(Duration::from_secs(20), |o| pty::contains(o, b"\x1b[c")),
        "{}: no queries came: {:?}",
        t.name,
        String::from_utf8_lossy(&term.output)
    );
    let asked = Instant::now();
    term.write(key);
    std::thread::sleep(t.delay);
    let mut answer = String::new();
    for a in [
        t.xtversion.map(|v| format!("\x1bP>|{v}\x1b\\")),
        t.kitty.map(String::from),
        t.cell.map(String::from),
        t.da1.map(String::from),
    ]
    .into_iter()
    .flatten()
    {
        answer.push_str(&a);
    }
    if !answer.is_empty() {
        term.write(answer.as_bytes());
    }
    let status = term.wait(Duration::from_secs(20));
    let took = asked.elapsed();
    assert!(status.is_some(), "{}: the program did not end", t.name);
    let after = pty::termios(std::os::fd::AsRawFd::as_raw_fd(&term.slave));
    assert_eq!(
        term.initial, after,
        "{}: the terminal was not left as found",
        t.name
    );
    (term, took)
}

/// The JSON document in a program's pty output.
fn json_in(output: &[u8]) -> serde_json::Value {
    let text = String::from_utf8_lossy(output).replace("\r\n", "\n");
    let start = text.find('{').expect("JSON in the output");
    let end = text.rfind('}').expect("JSON in the output");
    serde_json::from_str(&text[start..=end]).expect("valid JSON")
}

/// A command with none of the caller's terminal hints (tests may run in tmux).
fn clean(args: &[&str]) -> Command {
    let mut c = Command::new(bin());
    c.args(args)
        .env_clear()
        .env("PATH", std::env::var("PATH").unwrap_or_default())
        .env("TERM", "xterm-256color")
        .env("NODEVICE_SELECT", "1");
    c
}

#[test]
fn every_known_terminal_gets_its_protocol_fast_and_no_key_is_lost() {
    for t in profiles() {
        let (term, took) = play(&t, &mut clean(&["doctor", "--json"]), b"j", (0, 0));
        let d = json_in(&term.output);
        assert_eq!(d["graphics"], t.expect, "{}: {d:#}", t.name);
        let probe = &d["probe"];
        assert_eq!(
            probe["typed"], "j",
            "{}: the key typed was lost: {d:#}",
            t.name
        );
        let ms = probe["millis"].as_f64().unwrap();
        let capped = probe["capped"].as_bool().unwrap();
        assert_eq!(capped, t.da1.is_none(), "{}", t.name);
        // Bounds that load cannot break: a silent terminal is waited for the
        // whole cap (about 1 s, never less); an answering one stops the probe
        // when DA1 arrives, before the cap (`capped` false says it was the
        // answer, not the clock, that ended it), so well under it.
        if capped {
            assert!(ms >= 900.0, "{}: gave up after {ms} ms", t.name);
            let note = d["note"].as_str().unwrap();
            assert!(note.contains("did not answer"), "{note}");
        } else {
            assert!(ms < 900.0, "{}: probe took {ms} ms", t.name);
        }
        if t.cell.is_some() && t.expect != "Halfblocks" {
            assert_eq!(d["cell_pixels"], serde_json::json!([10, 20]), "{}", t.name);
            assert_eq!(d["cell_source"], "CSI 16 t", "{}", t.name);
        }
        eprintln!(
            "{:32} {:10} probe {ms:7.1} ms, program ended {:6.1} ms after the queries",
            t.name,
            t.expect,
            took.as_secs_f64() * 1e3
        );
    }
}

#[test]
fn the_kernels_cell_size_wins_when_plausible() {
    let t = p(
        "kitty",
        Some("kitty(0.35.2)"),
        OK,
        Some("\x1b[?62;c"),
        "Kitty",
    );
    let (term, _) = play(&t, &mut clean(&["doctor", "--json"]), b"", (1080, 880));
    let d = json_in(&term.output);
    assert_eq!(d["cell_pixels"], serde_json::json!([9, 22]), "{d:#}");
    assert_eq!(d["cell_source"], "TIOCGWINSZ");
}

/// A small dataset for `inspect` and `preview`.
fn dataset(dir: &Path) -> PathBuf {
    let path = dir.join("scene.tif");
    pcimg::store::write_part(&path, &pcimg::synth::scene(20_000, 3), &Default::default()).unwrap();
    path
}

#[test]
fn a_key_typed_during_the_probe_reaches_the_inspector() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let t = p(
        "xterm -ti vt340",
        Some("XTerm(379)"),
        None,
        Some("\x1b[?63;1;2;4;6;9;15;16;22;28c"),
        "Sixel",
    );
    // `q` typed before the terminal answered: the inspector must quit on it alone.
    let mut cmd = clean(&["inspect", ds.to_str().unwrap()]);
    let (term, took) = play(&t, &mut cmd, b"q", (1200, 800));
    assert!(took < Duration::from_secs(10), "quit after {took:?}");
    // It left the alternate screen it entered.
    assert!(pty::contains(&term.output, b"\x1b[?1049l"));
}

#[test]
fn the_inspector_draws_kitty_placeholders_and_deletes_its_image_on_exit() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let t = p(
        "kitty",
        Some("kitty(0.35.2)"),
        OK,
        Some("\x1b[?62;c"),
        "Kitty",
    );
    let mut cmd = clean(&["inspect", ds.to_str().unwrap(), "--renderer", "cpu"]);
    let mut term = Pty::spawn(&mut cmd, (160, 48), (1600, 960));
    assert!(term.read_until(Duration::from_secs(20), |o| pty::contains(o, b"\x1b[c")));
    let answers = format!(
        "\x1bP>|{}\x1b\\{}\x1b[6;20;10t{}",
        t.xtversion.unwrap(),
        t.kitty.unwrap(),
        t.da1.unwrap()
    );
    term.write(answers.as_bytes());
    // The first frame: a transmission with a virtual placement, and placeholders.
    let drawn = term.read_until(Duration::from_secs(30), |o| {
        pty::contains(o, b",U=1,") && pty::contains(o, "\u{10EEEE}".as_bytes())
    });
    assert!(drawn, "no kitty frame with placeholders");
    let out = String::from_utf8_lossy(&term.output).to_string();
    let head = &out[out.find("\x1b_Ga=T").unwrap()..];
    assert!(
        head.starts_with("\x1b_Ga=T,q=2,i=7365481,f=24,o=z,s="),
        "{}",
        &head[..80]
    );
    term.write(b"q");
    assert!(term.wait(Duration::from_secs(10)).is_some());
    assert!(pty::contains(
        &term.output,
        b"\x1b_Ga=d,d=I,i=7365481,q=2\x1b\\"
    ));
    assert_eq!(
        term.initial,
        pty::termios(std::os::fd::AsRawFd::as_raw_fd(&term.slave))
    );
}

/// How many times `needle` occurs in `hay`.
fn count(hay: &[u8], needle: &[u8]) -> usize {
    hay.windows(needle.len()).filter(|w| *w == needle).count()
}

#[test]
fn the_inspector_places_frames_directly_in_kitty_before_0_28() {
    // kitty 0.26.5 (Debian 12) and 0.21.2 (Ubuntu 22.04) reject `U=1`: no
    // placeholders; each frame is placed at the view's first cell instead.
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let mut cmd = clean(&["inspect", ds.to_str().unwrap(), "--renderer", "cpu"]);
    let mut term = Pty::spawn(&mut cmd, (160, 48), (1600, 960));
    assert!(term.read_until(Duration::from_secs(20), |o| pty::contains(o, b"\x1b[c")));
    term.write(b"\x1bP>|kitty(0.26.5)\x1b\\\x1b_Gi=31;OK\x1b\\\x1b[6;20;10t\x1b[?62;c");
    let drawn = term.read_until(Duration::from_secs(30), |o| {
        pty::contains(o, b"\x1b_Ga=T,q=2,i=7365481,") && pty::contains(o, b"m=0;")
    });
    assert!(drawn, "no kitty frame");
    let out = String::from_utf8_lossy(&term.output).to_string();
    let at = out.find("\x1b_Ga=T").unwrap();
    let head = &out[at..];
    assert!(head.contains(",C=1,"), "{}", &head[..90]);
    // Below text, so the overlays (scale bar, crosshair, picks) show over it;
    // the pane erased first, so no text left there does.
    assert!(head.contains(",z=-1073741825,"), "{}", &head[..90]);
    let before = &out[..at];
    let last = before.rfind("\x1b[").unwrap();
    assert!(
        before[last..].ends_with('A') && before[..last].ends_with("X\x1b[1B"),
        "{:?}",
        &before[before.len().saturating_sub(40)..]
    );
    assert!(!out.contains("U=1") && !out.contains('\u{10EEEE}'));
    // A key that orbits brings a new frame under the same id (it replaces the
    // last); the help takes the image off (kitty draws it above text).
    let frames = |t: &Pty| count(&t.output, b"\x1b_Ga=T,q=2,i=7365481,");
    let n = frames(&term);
    term.write(b"l");
    assert!(term.read_until(Duration::from_secs(30), |o| count(
        o,
        b"\x1b_Ga=T,q=2,i=7365481,"
    ) > n));
    term.write(b"?");
    assert!(term.read_until(Duration::from_secs(10), |o| pty::contains(
        o,
        b"keys (? closes)"
    )));
    let out = String::from_utf8_lossy(&term.output).to_string();
    let help = out.find("keys (? closes)").unwrap();
    let deleted = out[..help].rfind("\x1b_Ga=d,d=I,i=7365481,q=2\x1b\\");
    let placed = out[..help].rfind("\x1b_Ga=T");
    assert!(
        deleted > placed,
        "the image was not taken off before the help"
    );
    let n = frames(&term);
    term.write(b"?");
    assert!(
        term.read_until(Duration::from_secs(10), |o| count(
            o,
            b"\x1b_Ga=T,q=2,i=7365481,"
        ) > n),
        "the image was not placed again after the help"
    );
    term.write(b"q");
    assert!(term.wait(Duration::from_secs(10)).is_some());
    assert!(pty::contains(
        &term.output,
        b"\x1b_Ga=d,d=I,i=7365481,q=2\x1b\\"
    ));
}

/// Starts `shell` in a tmux session, attaches a client from a pty whose other
/// side answers tmux's own queries as `outer` (XTVERSION text, DA1), and returns
/// the client's pty once `done` exists.
fn in_tmux(tmux: &Tmux, shell: &str, outer: &str, da1: &str, done: &Path) -> Pty {
    in_tmux_with(tmux, shell, outer, da1, done, None)
}

/// [`in_tmux`], the client attached with tmux terminal `features` (`-T`).
fn in_tmux_with(
    tmux: &Tmux,
    shell: &str,
    outer: &str,
    da1: &str,
    done: &Path,
    features: Option<&str>,
) -> Pty {
    tmux.start(shell);
    let mut attach = tmux.cmd();
    if let Some(f) = features {
        attach.args(["-T", f]);
    }
    attach
        .args(["attach", "-t", "t"])
        .env("TERM", "xterm-256color");
    let mut client = Pty::spawn(&mut attach, (120, 40), (1200, 800));
    let end = Instant::now() + Duration::from_secs(20);
    let mut answered = (false, false);
    while Instant::now() < end && !done.exists() {
        client.read_some(Duration::from_millis(20));
        if !answered.0 && pty::contains(&client.output, b"\x1b[>q") {
            client.write(format!("\x1bP>|{outer}\x1b\\").as_bytes());
            answered.0 = true;
        }
        if !answered.1 && pty::contains(&client.output, b"\x1b[c") {
            client.write(da1.as_bytes());
            answered.1 = true;
        }
    }
    client.read_for(Duration::from_millis(200));
    assert!(done.exists(), "the command in tmux did not finish");
    client
}

#[test]
fn inside_tmux_the_server_is_asked_about_the_outer_terminal() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (outer, da1, expect, placeholders) in [
        ("kitty(0.35.2)", "\x1b[?62;c", "Kitty", true),
        (
            "XTerm(379)",
            "\x1b[?63;1;2;4;6;9;15;16;22;28c",
            "Halfblocks",
            false,
        ),
    ] {
        let tmux = Tmux::new(&format!("terminals-{expect}"));
        let out = dir.path().join(format!("{expect}.json"));
        let done = dir.path().join(format!("{expect}.done"));
        // Wait for the client, so that tmux knows the outer terminal.
        let shell = format!(
            "while [ -z \"$(tmux display -p '#{{client_name}}')\" ]; do sleep 0.05; done; sleep 0.3; {} doctor --json > {} 2>&1; touch {}",
            bin(),
            out.display(),
            done.display()
        );
        let _client = in_tmux(&tmux, &shell, outer, da1, &done);
        let d: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        assert_eq!(d["graphics"], expect, "{d:#}");
        assert_eq!(d["placeholders"], placeholders, "{d:#}");
        assert!(
            d["probe"].is_null(),
            "tmux itself must not be probed: {d:#}"
        );
        let info = &d["tmux"]["Ok"];
        assert_eq!(info["termtype"], outer, "{d:#}");
        assert!(info["version"].as_str().unwrap().starts_with('3'));
        let ms = info["millis"].as_f64().unwrap();
        assert!(ms < 500.0, "tmux display took {ms} ms");
        if expect == "Halfblocks" {
            let note = d["note"].as_str().unwrap();
            assert!(note.contains("tmux") && note.contains("would"), "{note}");
        }
        eprintln!("tmux with outer {outer}: {expect}, tmux asked in {ms:.1} ms");
    }
}

#[test]
fn text_in_tmux_is_in_256_colours_unless_the_client_has_rgb() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (features, depth) in [(None, "C256"), (Some("RGB"), "True")] {
        let name = if features.is_some() { "rgb" } else { "no-rgb" };
        let tmux = Tmux::new(&format!("text-{name}"));
        let out = dir.path().join(format!("{name}.json"));
        let done = dir.path().join(format!("{name}.done"));
        // The pane's TERM as most tmux set-ups have it; no COLORTERM.
        let shell = format!(
            "while [ -z \"$(tmux display -p '#{{client_name}}')\" ]; do sleep 0.05; done; sleep 0.3; \
             env -u COLORTERM TERM=screen-256color {} doctor --json > {} 2>&1; touch {}",
            bin(),
            out.display(),
            done.display()
        );
        let _client = in_tmux_with(
            &tmux,
            &shell,
            // A terminal tmux knows nothing of (tmux gives XTerm RGB itself).
            "Termite(1.0)",
            "\x1b[?62;c",
            &done,
            features,
        );
        let d: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        assert_eq!(d["graphics"], "Halfblocks", "{d:#}");
        assert_eq!(d["text"]["depth"], depth, "{d:#}");
        assert_eq!(d["text"]["set"], "quadrants", "{d:#}");
        eprintln!(
            "tmux, client features {features:?}: {}",
            d["text"]["reason"]
        );
    }
}

#[test]
fn preview_in_tmux_sends_kitty_placeholders_through_to_the_outer_terminal() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let tmux = Tmux::new("preview");
    let done = dir.path().join("done");
    let before = dir.path().join("before");
    let shell = format!(
        "while [ -z \"$(tmux display -p '#{{client_name}}')\" ]; do sleep 0.05; done; sleep 0.3; \
         tmux show -pv allow-passthrough > {}; {} preview {} --cols 40 || true; sleep 0.2; touch {}; sleep 30",
        before.display(),
        bin(),
        ds.display(),
        done.display()
    );
    let client = in_tmux(&tmux, &shell, "kitty(0.35.2)", "\x1b[?62;c", &done);
    // The image reached the outer terminal unwrapped: a virtual placement.
    let out = &client.output;
    assert!(
        pty::contains(out, b"\x1b_Ga=T,q=2,i=") && pty::contains(out, b",U=1,"),
        "no kitty image came through tmux"
    );
    // Placeholder cells, drawn by tmux as text.
    assert!(pty::contains(out, "\u{10EEEE}".as_bytes()));
    // allow-passthrough was put back as it was (not set on the pane).
    let after = tmux.run(&["show", "-pv", "-t", "t", "allow-passthrough"]);
    assert_eq!(
        after.trim(),
        std::fs::read_to_string(&before).unwrap().trim()
    );
}

#[test]
fn real_xterm_in_vt340_mode_gets_sixel_without_a_flag() {
    if !installed(&["xterm", "Xvfb"], "xterm, xvfb") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Started on a free display, used once it accepts clients (no fixed wait).
    let (xvfb, display) = start_xvfb("1280x1024x24");
    let out = dir.path().join("doctor.json");
    let status = Command::new("xterm")
        .args(["-display", &display, "-ti", "vt340", "-e", "sh", "-c"])
        .arg(format!("{} doctor --json > {}", bin(), out.display()))
        .env_remove("TMUX")
        .env_remove("KITTY_WINDOW_ID")
        .env_remove("TERM_PROGRAM")
        .status();
    drop(xvfb);
    assert!(status.unwrap().success());
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(d["graphics"], "Sixel", "{d:#}");
    let probe = &d["probe"];
    assert!(
        probe["replies"]["xtversion"]
            .as_str()
            .unwrap()
            .starts_with("XTerm(")
    );
    assert_eq!(probe["capped"], false);
    eprintln!("xterm -ti vt340: sixel, probe {} ms", probe["millis"]);
}

/// A child process ended (and reaped) when dropped, should the test fail first.
struct Reaped(std::process::Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts Xvfb on a display it finds free, and returns once it accepts clients
/// (it writes the display's number to `-displayfd` then).
fn start_xvfb(size: &str) -> (Reaped, String) {
    use std::io::BufRead as _;
    let mut child = Command::new("Xvfb")
        .args(["-displayfd", "1", "-screen", "0", size, "-nolisten", "tcp"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("Xvfb starts");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let n = line.trim();
    assert!(!n.is_empty(), "Xvfb did not start");
    let display = format!(":{n}");
    (Reaped(child), display)
}

/// The screen of `display`, as RGB (ImageMagick's `import`).
fn screenshot(display: &str) -> image::RgbImage {
    let out = Command::new("import")
        .args(["-display", display, "-window", "root", "png:-"])
        .stderr(std::process::Stdio::null())
        .output()
        .expect("import runs");
    assert!(out.status.success(), "import failed");
    image::load_from_memory(&out.stdout).unwrap().to_rgb8()
}

/// Kitty's background in the test (no frame of ours has this colour).
const KITTY_BG: [u8; 3] = [0x30, 0x50, 0xa0];

/// What a rectangle of a screenshot holds: the share of its pixels in kitty's
/// own background (a view without a picture, or glyphs on it), the share lit by
/// the picture (neither background: bright, or coloured), and how many distinct
/// colours those have (a picture has many; text has a few and their blends).
#[derive(Debug, Clone, Copy)]
struct ViewPixels {
    background: f64,
    lit: f64,
    colours: usize,
}

fn view_pixels(img: &image::RgbImage, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> ViewPixels {
    let mut n = 0usize;
    let mut bg = 0usize;
    let mut lit = 0usize;
    let mut colours = std::collections::HashSet::new();
    for y in y0..y1.min(img.height()) {
        for x in x0..x1.min(img.width()) {
            let p = img.get_pixel(x, y).0;
            n += 1;
            if p == KITTY_BG {
                bg += 1;
            } else if p.iter().any(|&c| c > 40) {
                lit += 1;
                colours.insert(p);
            }
        }
    }
    let n = n.max(1) as f64;
    ViewPixels {
        background: bg as f64 / n,
        lit: lit as f64 / n,
        colours: colours.len(),
    }
}

impl ViewPixels {
    /// The view is covered by a picture: hardly any of kitty's background shows
    /// (placeholder glyphs drawn as text leave most of it), and enough of it is
    /// lit in enough colours to be a rendered scan.
    fn picture(&self) -> bool {
        self.background < 0.02 && self.lit > 0.005 && self.colours >= 24
    }
}

/// The share of the rectangle's pixels that differ between two screenshots.
fn changed(
    a: &image::RgbImage,
    b: &image::RgbImage,
    (x0, y0, x1, y1): (u32, u32, u32, u32),
) -> f64 {
    let mut n = 0usize;
    let mut d = 0usize;
    for y in y0..y1.min(a.height()).min(b.height()) {
        for x in x0..x1.min(a.width()).min(b.width()) {
            n += 1;
            d += usize::from(a.get_pixel(x, y) != b.get_pixel(x, y));
        }
    }
    d as f64 / n.max(1) as f64
}

/// Waits (polling the screen, up to `limit`) until the view's pixels pass `ok`;
/// returns them, or panics with the last seen.
fn wait_for_view(
    display: &str,
    rect: (u32, u32, u32, u32),
    limit: Duration,
    what: &str,
    ok: impl Fn(&ViewPixels, &image::RgbImage) -> bool,
) -> (ViewPixels, image::RgbImage) {
    let end = Instant::now() + limit;
    loop {
        let shot = screenshot(display);
        let v = view_pixels(&shot, rect);
        if ok(&v, &shot) {
            return (v, shot);
        }
        if Instant::now() > end {
            let path = std::env::temp_dir().join(format!("pcimg-kitty-{}.png", std::process::id()));
            let _ = shot.save(&path);
            panic!(
                "{what}: not seen within {limit:?}; last {v:?} (screen saved as {})",
                path.display()
            );
        }
        std::thread::sleep(Duration::from_millis(150));
    }
}

/// What `pcimg doctor --json` wrote to `doctor`, run first in a terminal
/// (`term`, named in failures) that then starts the inspector: waited for
/// until complete (doctor ends before the inspector starts), at most 60 s.
fn doctor_in(doctor: &Path, term: &mut Reaped, name: &str) -> serde_json::Value {
    let end = Instant::now() + Duration::from_secs(60);
    loop {
        let text = std::fs::read_to_string(doctor).unwrap_or_default();
        if let Ok(v) = serde_json::from_str(&text) {
            return v;
        }
        assert!(
            Instant::now() < end,
            "{name} did not run pcimg doctor within 60 s"
        );
        assert!(term.0.try_wait().unwrap().is_none(), "{name} ended early");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The inspector's view in pixels of the terminal's window at the screen's
/// top-left: its cells less a margin of two (ui::areas: the left panels take
/// 2/5 of the columns, at most 72; status and hint rows below), from the
/// window size `doctor` reported.
fn view_rect(d: &serde_json::Value) -> (u32, u32, u32, u32) {
    let w = &d["winsize"];
    let (cols, rows) = (
        w["cols"].as_u64().unwrap() as u32,
        w["rows"].as_u64().unwrap() as u32,
    );
    let (cw, ch) = (
        w["width_px"].as_u64().unwrap() as u32 / cols,
        w["height_px"].as_u64().unwrap() as u32 / rows,
    );
    let left = (cols * 2 / 5).clamp(20, 72);
    let rect = ((left + 3) * cw, 3 * ch, (cols - 3) * cw, (rows - 5) * ch);
    assert!(
        rect.0 + 10 * cw < rect.2 && rect.1 + 5 * ch < rect.3,
        "{cols}×{rows} cells"
    );
    rect
}

/// Debian's mlterm (3.9) draws sixel: the inspector chooses it by itself and
/// its view holds the picture, replaced by the next when the camera turns
/// (keys typed by xdotool), and `q` ends it.
#[test]
fn real_mlterm_shows_the_inspectors_view_in_sixel() {
    if !installed(
        &["mlterm", "Xvfb", "import", "xdotool"],
        "mlterm, xvfb, imagemagick, xdotool",
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    inspector_in_mlterm(dir.path(), "mlterm", |script| script);
}

/// tmux built with sixel (3.4 and later, `./configure --enable-sixel`) passes
/// the inspector's sixel through to the terminal outside it (mlterm): the
/// inspector chooses sixel by itself inside tmux and the view holds the
/// picture. Debian 12's own tmux (3.3a) is built without sixel, as most
/// distributions' are; bookworm-backports' tmux (3.5a) has it, and `.ci/run`
/// unpacks that package beside the build (the system's tmux stays) and names
/// it in `PCIMG_TMUX_SIXEL`. Elsewhere:
/// `PCIMG_TMUX_SIXEL=/path/to/tmux cargo test --test terminals tmux_built`
/// (docs/guide.md, "Terminals").
#[test]
fn tmux_built_with_sixel_passes_the_inspectors_sixel_through_to_mlterm() {
    let Some(tmux) = std::env::var_os("PCIMG_TMUX_SIXEL") else {
        assert!(
            std::env::var("CI").ok().as_deref() != Some("true"),
            "PCIMG_TMUX_SIXEL must name a tmux built with --enable-sixel in CI \
             (.ci/run unpacks bookworm-backports' tmux)"
        );
        eprintln!(
            "note: PCIMG_TMUX_SIXEL names no tmux built with sixel, skipping this test outside CI"
        );
        return;
    };
    let tmux = tmux.to_string_lossy().into_owned();
    let version = Command::new(&tmux).arg("-V").output().expect("tmux -V");
    let version = String::from_utf8_lossy(&version.stdout).trim().to_string();
    assert!(installed(
        &["mlterm", "Xvfb", "import", "xdotool"],
        "mlterm, xvfb, imagemagick, xdotool",
    ));
    let dir = tempfile::tempdir().unwrap();
    // Its own server and an empty configuration with no status line, so the
    // pane is the whole window.
    let conf = dir.path().join("tmux.conf");
    std::fs::write(&conf, "set -g status off\n").unwrap();
    let socket = format!("pcimg-sixel-{}", std::process::id());
    struct Server(String, String);
    impl Drop for Server {
        fn drop(&mut self) {
            let _ = Command::new(&self.0)
                .args(["-L", &self.1, "kill-server"])
                .output();
        }
    }
    let _server = Server(tmux.clone(), socket.clone());
    let d = inspector_in_mlterm(dir.path(), &version, |script| {
        format!(
            "exec {tmux} -L {socket} -f {conf} new-session {script:?}",
            conf = conf.display()
        )
    });
    // Chosen because tmux itself draws sixel, not passed through.
    assert_eq!(d["reason"], "tmux draws sixel", "{d:#}");
    assert_eq!(d["passthrough"], false, "{d:#}");
    let features = d["tmux"]["Ok"]["features"].as_str().unwrap_or_default();
    assert!(features.split(',').any(|f| f == "sixel"), "{d:#}");
}

/// The inspector in mlterm under Xvfb, started by `wrap`'s shell command
/// around the one that runs `doctor` then `inspect`: doctor chooses sixel,
/// the view holds the picture, keys typed by xdotool turn the camera and the
/// picture changes, and `q` ends it. Returns what doctor said.
fn inspector_in_mlterm(
    dir: &Path,
    name: &str,
    wrap: impl Fn(String) -> String,
) -> serde_json::Value {
    let ds = dataset(dir);
    let (_xvfb, display) = start_xvfb("1024x768x24");
    let doctor = dir.join("doctor.json");
    let script = wrap(format!(
        "{bin} doctor --json > {doctor}; exec {bin} inspect {ds} --renderer cpu",
        bin = bin(),
        doctor = doctor.display(),
        ds = ds.display()
    ));
    let bg = format!("#{:02x}{:02x}{:02x}", KITTY_BG[0], KITTY_BG[1], KITTY_BG[2]);
    let mut term = Reaped(
        Command::new("mlterm")
            .args([
                "-display",
                &display,
                "-g",
                "96x32+0+0",
                "-bg",
                &bg,
                "-fg",
                "white",
            ])
            .args(["-e", "sh", "-c", &script])
            .env_remove("TMUX")
            .env_remove("TMUX_PANE")
            .env_remove("KITTY_WINDOW_ID")
            .env_remove("TERM_PROGRAM")
            .env_remove("COLORTERM")
            .env("NODEVICE_SELECT", "1")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("mlterm starts"),
    );
    let d = doctor_in(&doctor, &mut term, name);
    assert_eq!(d["graphics"], "Sixel", "{name}: {d:#}");
    let rect = view_rect(&d);
    // (Sixel's palette holds fewer colours than kitty's frames: the view is
    // covered, and lit in more colours than text would be.)
    let picture = |v: &ViewPixels, _: &image::RgbImage| {
        v.background < 0.02 && v.lit > 0.005 && v.colours >= 8
    };
    let (first, shot) = wait_for_view(
        &display,
        rect,
        Duration::from_secs(60),
        &format!("{name}: the first frame"),
        picture,
    );
    let send = |keys: &str| {
        let ok = Command::new("xdotool")
            .args([
                "search",
                "--sync",
                "--class",
                "mlterm",
                "windowfocus",
                "--sync",
                "type",
            ])
            .args(["--delay", "30", keys])
            .env("DISPLAY", &display)
            .output()
            .is_ok_and(|o| o.status.success());
        assert!(ok, "xdotool could not type {keys}");
    };
    send("llll");
    let (turned, _) = wait_for_view(
        &display,
        rect,
        Duration::from_secs(30),
        &format!("{name}: the orbited frame"),
        |v, now| picture(v, now) && changed(&shot, now, rect) > 0.01,
    );
    send("q");
    let end = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(s) = term.0.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < end, "the inspector did not quit on q");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{name}: mlterm ended with {status}");
    eprintln!("{name}: sixel; view {first:?}, orbited {turned:?}");
    d
}

#[test]
fn real_kitty_shows_the_inspectors_view_placed_directly_before_0_28() {
    if !installed(&["kitty", "Xvfb", "import"], "kitty, xvfb, imagemagick") {
        return;
    }
    let started = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let (_xvfb, display) = start_xvfb("1024x768x24");
    let doctor = dir.path().join("doctor.json");
    let socket = dir.path().join("kitty.sock");
    let kitty_log = dir.path().join("kitty.stderr");
    // Kitty's own window at the screen's top-left (no window manager), in a
    // background colour no frame has; doctor first (what kitty says it is), then
    // the inspector.
    let script = format!(
        "{bin} doctor --json > {doctor}; exec {bin} inspect {ds} --renderer cpu",
        bin = bin(),
        doctor = doctor.display(),
        ds = ds.display()
    );
    let bg = format!(
        "background=#{:02x}{:02x}{:02x}",
        KITTY_BG[0], KITTY_BG[1], KITTY_BG[2]
    );
    let mut kitty = Reaped(
        Command::new("kitty")
            .args(["--config", "NONE", "-o", &bg, "-o", "foreground=#ffffff"])
            .args([
                "-o",
                "remember_window_size=no",
                "-o",
                "initial_window_width=960",
            ])
            .args([
                "-o",
                "initial_window_height=600",
                "-o",
                "allow_remote_control=yes",
            ])
            .arg("--listen-on")
            .arg(format!("unix:{}", socket.display()))
            .args(["sh", "-c", &script])
            .env_remove("TMUX")
            .env_remove("TMUX_PANE")
            .env_remove("KITTY_WINDOW_ID")
            .env_remove("TERM_PROGRAM")
            .env_remove("LC_TERMINAL")
            .env("DISPLAY", &display)
            .env("LIBGL_ALWAYS_SOFTWARE", "1")
            .env("NODEVICE_SELECT", "1")
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&kitty_log).unwrap())
            .spawn()
            .expect("kitty starts"),
    );
    let d = doctor_in(&doctor, &mut kitty, "kitty");
    assert_eq!(d["graphics"], "Kitty", "{d:#}");
    let version = d["probe"]["replies"]["xtversion"]
        .as_str()
        .unwrap_or("")
        .to_string();
    let v = pcimg::term::detect::kitty_version(&version)
        .unwrap_or_else(|| panic!("kitty said no version: {d:#}"));
    let placeholders = v >= pcimg::term::detect::KITTY_PLACEHOLDERS_SINCE;
    assert_eq!(d["kitty_placeholders"], placeholders, "{d:#}");
    let rect = view_rect(&d);
    let send = |text: &str| {
        let ok = Command::new("kitty")
            .args(["@", "--to"])
            .arg(format!("unix:{}", socket.display()))
            .args(["send-text", text])
            .env("DISPLAY", &display)
            .output()
            .is_ok_and(|o| o.status.success());
        assert!(ok, "kitty @ send-text {text} failed");
    };

    let picture = |v: &ViewPixels, _: &image::RgbImage| v.picture();
    let (first, shot) = wait_for_view(
        &display,
        rect,
        Duration::from_secs(60),
        "the first frame",
        picture,
    );
    let to_frame = started.elapsed();
    // Frames that follow (the camera orbits) replace the first: the view holds
    // a picture, a different one.
    send("llll");
    let (turned, _) = wait_for_view(
        &display,
        rect,
        Duration::from_secs(30),
        "the orbited frame",
        |v, now| v.picture() && changed(&shot, now, rect) > 0.01,
    );
    // The help over the view: a directly placed image is taken off for it (else it
    // would hide the help), and placed again when the help closes.
    send("?");
    if !placeholders {
        wait_for_view(
            &display,
            rect,
            Duration::from_secs(30),
            "the help without the image",
            |v, _| v.background > 0.3,
        );
    }
    send("?");
    wait_for_view(
        &display,
        rect,
        Duration::from_secs(30),
        "the frame after the help",
        picture,
    );
    send("q");
    let end = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(s) = kitty.0.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < end, "the inspector did not quit on q");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "kitty ended with {status}");
    let log = std::fs::read_to_string(&kitty_log).unwrap();
    assert!(
        !log.contains("PARSE ERROR"),
        "kitty could not parse what it was sent:\n{log}"
    );
    eprintln!(
        "{version}: {} ; first frame {:.1} s after start, view {first:?}, orbited {turned:?}, all {:.1} s",
        if placeholders {
            "Unicode placeholders"
        } else {
            "placed directly"
        },
        to_frame.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
}

/// Whether every program of `tools` is installed (`which`). In CI (`CI=true`)
/// a missing one is a failure (`.ci/run` installs `packages`); elsewhere the
/// caller skips with a note.
fn installed(tools: &[&str], packages: &str) -> bool {
    let have = tools.iter().all(|p| {
        Command::new("which")
            .arg(p)
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if !have {
        assert!(
            std::env::var("CI").ok().as_deref() != Some("true"),
            "{} are required in CI (.ci/run installs {packages})",
            tools.join(", ")
        );
        eprintln!(
            "note: one of {} not found, skipping this test outside CI",
            tools.join(", ")
        );
    }
    have
}

/// Whether a pixel is the overlays' white (bold bright white, SGR 1;97).
fn white(p: &image::Rgb<u8>) -> bool {
    let [r, g, b] = p.0;
    r.min(g).min(b) >= 200 && r.max(g).max(b) - r.min(g).min(b) <= 40
}

#[test]
fn real_xterm_in_text_mode_draws_the_scale_bar_label_in_one_text_row() {
    if !installed(&["xterm", "Xvfb", "import"], "xterm, xvfb, imagemagick") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let (_xvfb, display) = start_xvfb("1280x1024x24");
    let doctor = dir.path().join("doctor.json");
    // Colours without white (viridis), in a window of kitty's test colours:
    // the only white on screen is the overlays'.
    let script = format!(
        "{bin} doctor --json > {doctor}; exec {bin} inspect {ds} --renderer cpu \
         --protocol text --color height --ramp viridis",
        bin = bin(),
        doctor = doctor.display(),
        ds = ds.display()
    );
    let bg = format!("#{:02x}{:02x}{:02x}", KITTY_BG[0], KITTY_BG[1], KITTY_BG[2]);
    let mut xterm = Reaped(
        Command::new("xterm")
            .args(["-display", &display, "-geometry", "120x40", "-bg", &bg])
            .args(["-fg", "gray", "-e", "sh", "-c", &script])
            .env_remove("TMUX")
            .env_remove("KITTY_WINDOW_ID")
            .env_remove("TERM_PROGRAM")
            .env("NODEVICE_SELECT", "1")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("xterm starts"),
    );
    // doctor ends before the inspector starts: complete once it parses.
    let end = Instant::now() + Duration::from_secs(60);
    let d: serde_json::Value = loop {
        if let Ok(v) = serde_json::from_str(&std::fs::read_to_string(&doctor).unwrap_or_default()) {
            break v;
        }
        assert!(Instant::now() < end, "xterm did not run pcimg within 60 s");
        assert!(xterm.0.try_wait().unwrap().is_none(), "xterm ended early");
        std::thread::sleep(Duration::from_millis(50));
    };
    // Cells in pixels: xterm reports its text area, inside a border.
    let w = &d["winsize"];
    let (cols, rows) = (
        w["cols"].as_u64().unwrap() as u32,
        w["rows"].as_u64().unwrap() as u32,
    );
    let (wpx, hpx) = (
        w["width_px"].as_u64().unwrap() as u32,
        w["height_px"].as_u64().unwrap() as u32,
    );
    let (cw, ch) = (wpx / cols, hpx / rows);
    assert!(cw >= 4 && ch >= 8, "{w}");
    let (ox, oy) = ((wpx - cols * cw) / 2, (hpx - rows * ch) / 2);
    // ui::areas: the view's inside starts a column right of the left panels'
    // 2/5 (at most 72), and ends a row above the view's border, the status and
    // the hint rows. The bar is on its last row, a cell in; the label above.
    let left = (cols * 2 / 5).clamp(20, 72);
    let bar_row = rows - 4;
    let x0 = ox + (left + 2) * cw;
    let x1 = x0 + 24 * cw;
    let row_px = |r: u32| oy + r * ch;
    let whites = |shot: &image::RgbImage, y0: u32, y1: u32| -> Vec<(u32, u32)> {
        let mut v = Vec::new();
        for y in y0..y1.min(shot.height()) {
            for x in x0..x1.min(shot.width()) {
                if white(shot.get_pixel(x, y)) {
                    v.push((x, y));
                }
            }
        }
        v
    };
    // Waits until the bar shows: a horizontal stroke two cells long or more.
    let end = Instant::now() + Duration::from_secs(60);
    let shot = loop {
        let shot = screenshot(&display);
        let bar = whites(&shot, row_px(bar_row), row_px(bar_row + 1));
        let longest = (row_px(bar_row)..row_px(bar_row + 1))
            .map(|y| bar.iter().filter(|p| p.1 == y).count() as u32)
            .max()
            .unwrap_or(0);
        if longest >= 2 * cw {
            break shot;
        }
        if Instant::now() > end {
            let path = std::env::temp_dir().join(format!("pcimg-xterm-{}.png", std::process::id()));
            let _ = shot.save(&path);
            panic!(
                "no scale bar within 60 s (screen saved as {})",
                path.display()
            );
        }
        std::thread::sleep(Duration::from_millis(150));
    };
    // The label's white: in the cell row above the bar, and nowhere above it.
    let label = whites(&shot, row_px(bar_row - 4), row_px(bar_row));
    let top = label
        .iter()
        .map(|p| p.1)
        .min()
        .expect("a label over the bar");
    let bottom = label.iter().map(|p| p.1).max().unwrap();
    let path = std::env::temp_dir().join(format!("pcimg-xterm-{}.png", std::process::id()));
    if bottom - top + 1 > ch || top < row_px(bar_row - 1) {
        let _ = shot.save(&path);
    }
    assert!(
        bottom - top < ch && top >= row_px(bar_row - 1),
        "the label spans pixel rows {top}..={bottom}, a text row is {ch} px from {} \
         (screen saved as {})",
        row_px(bar_row - 1),
        path.display()
    );
    eprintln!(
        "xterm {cols}×{rows} cells of {cw}×{ch} px: label {} px high",
        bottom - top + 1
    );
}

/// The sizes of the sixel images in `out`, in the order sent (`"1;1;W;H`).
fn sixel_sizes(out: &[u8]) -> Vec<(u32, u32)> {
    let text = String::from_utf8_lossy(out);
    text.split("\x1bP0;1;0q\"1;1;")
        .skip(1)
        .filter_map(|s| {
            let end = s.find(|c: char| !c.is_ascii_digit() && c != ';')?;
            let (w, h) = s[..end].split_once(';')?;
            Some((w.parse().ok()?, h.parse().ok()?))
        })
        .collect()
}

#[test]
fn the_crosshair_and_picks_send_no_new_sixel_frame() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    // The coarsest level, loaded before the first frame: one frame, no redraws.
    let coarsest = pcimg::store::Dataset::open(&ds).unwrap().parts().unwrap()[0]
        .levels
        .len()
        - 1;
    let lod = coarsest.to_string();
    let args = [
        "inspect",
        ds.to_str().unwrap(),
        "--renderer",
        "cpu",
        "--protocol",
        "sixel",
        "--lod",
        &lod,
    ];
    let mut term = Pty::spawn(&mut clean(&args), (160, 48), (1600, 960));
    // Frames are the view's inside (ui::areas: 160 − 64 − 2 cells across,
    // 48 − 4 down) of 10×20 px cells; patches are a cell high.
    let frame = (94 * 10, 44 * 20);
    let frames = |o: &[u8]| sixel_sizes(o).iter().filter(|s| **s == frame).count();
    let patches = |o: &[u8]| {
        sixel_sizes(o)
            .into_iter()
            .filter(|&(w, h)| h == 20 && w <= 5 * 10)
            .count()
    };
    // The frame, then the scale bar's cells written over it.
    assert!(term.read_until(Duration::from_secs(30), |o| {
        let text = String::from_utf8_lossy(o);
        frames(o) == 1 && text.rfind('┤') > text.rfind("\x1bP0;1;0q")
    }));
    // Pick mode: the crosshair over the frame (its arms white on the default
    // background).
    term.write(b"x");
    assert!(term.read_until(Duration::from_secs(10), |o| pty::contains(
        o,
        "15;49m│".as_bytes()
    )));
    // Moved: the picture under the cells it left comes back as patches.
    term.write(b"l");
    assert!(
        term.read_until(Duration::from_secs(10), |o| patches(o) >= 1),
        "no patch: {:?}",
        sixel_sizes(&term.output)
    );
    // A pick: the point, no frame.
    term.write(b"\r");
    assert!(term.read_until(Duration::from_secs(10), |o| pty::contains(
        o,
        "picked ".as_bytes()
    ) || pty::contains(
        o,
        b"no point under"
    )));
    assert_eq!(frames(&term.output), 1, "{:?}", sixel_sizes(&term.output));
    term.write(b"q");
    term.write(b"q");
    assert!(term.wait(Duration::from_secs(10)).is_some());
}
