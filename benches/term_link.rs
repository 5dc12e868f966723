//! The inspector over a slow link, measured on a real pseudo-terminal: the binary
//! runs on a pty whose other side plays a terminal (answering the probe as xterm
//! `-ti vt340` for sixel, as kitty for kitty) and reads its output no faster than
//! the link allows. Keys are typed as a user holding the orbit key would; the
//! output stream is cut into frames, each with the time its last byte arrived.
//!
//! ```sh
//! cargo build --release && cargo run --release --example term_link -- [POINTS] [MBIT/S ...]
//! ```
//!
//! Reports per protocol and link speed: the probe's time, bytes per frame while
//! moving and at rest, first key → first frame, and last key → the full frame:
//! the first full-resolution frame after the last key (over a slow link it may
//! be in fewer colours), then the last one (the exact frame, which follows a
//! reduced one once the link is idle, and redraws as tiles arrive).
//!
//! Moving frames are told from full ones by their pixels: kitty ones are
//! smaller than the pane; sixel ones are enlarged, so every run of a colour
//! starts at a multiple of the reduction (2, 3 or 4 pixels).
//!
//! `TERM_LINK_BIN=path` measures another `pcimg` binary (an older build) with
//! the same harness.

#[path = "../tests/common/pty.rs"]
mod pty;

use pty::Pty;
use std::process::Command;
use std::time::{Duration, Instant};

/// What the played terminal draws.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Sixel,
    Kitty,
    Text,
}

/// Text frames: each draw of the inspector ends by hiding the cursor
/// (`ESC [ 0 m ESC [ ? 25 l`); a draw of at least 2 KB holds a frame's cells
/// (smaller ones are the status line alone). There are no reduced frames in
/// text: those that arrive before the last key count as moving.
fn text_frames(out: &[u8], log: &[(Instant, usize)], last_key: Instant) -> Vec<Seen> {
    let mark = b"\x1b[0m\x1b[?25l";
    let mut v = Vec::new();
    let (mut start, mut at) = (0, 0);
    while let Some(m) = find(out, mark, at) {
        let end = m + mark.len();
        if end - start >= 2048 {
            let t = arrival(log, end - 1);
            v.push(Seen {
                bytes: end - start,
                end: t,
                moving: t <= last_key,
            });
        }
        (start, at) = (end, end);
    }
    v
}

/// A frame found in the output: its bytes and when its last byte arrived.
struct Seen {
    bytes: usize,
    end: Instant,
    moving: bool,
}

fn find(h: &[u8], n: &[u8], from: usize) -> Option<usize> {
    h.get(from..)?
        .windows(n.len())
        .position(|w| w == n)
        .map(|p| p + from)
}

/// When output byte `offset` had arrived.
fn arrival(log: &[(Instant, usize)], offset: usize) -> Instant {
    log.iter()
        .find(|(_, len)| *len > offset)
        .map(|(t, _)| *t)
        .unwrap_or_else(Instant::now)
}

/// Whether a sixel image is a reduced frame enlarged by repeating pixels: every
/// change of sixel character within a colour's row of a band is at a multiple
/// of the same n > 1.
fn blocky(seg: &[u8]) -> bool {
    fn gcd(a: usize, b: usize) -> usize {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    let Some(q) = seg.iter().position(|&b| b == b'q') else {
        return false;
    };
    let (mut x, mut prev, mut g) = (0usize, None::<u8>, 0usize);
    let mut i = q + 1;
    while i < seg.len() {
        let b = seg[i];
        i += 1;
        let (ch, n) = match b {
            b'$' | b'-' => {
                (x, prev) = (0, None);
                continue;
            }
            b'!' => {
                let mut n = 0usize;
                while i < seg.len() && seg[i].is_ascii_digit() {
                    n = n * 10 + (seg[i] - b'0') as usize;
                    i += 1;
                }
                let Some(&c) = seg.get(i) else { break };
                i += 1;
                (c, n)
            }
            63..=126 => (b, 1),
            _ => continue,
        };
        if prev != Some(ch) && x > 0 {
            g = gcd(g, x);
            if g == 1 {
                return false;
            }
        }
        prev = Some(ch);
        x += n;
    }
    g > 1
}

/// Sixel frames: `ESC P 0;1;0 q` to `ESC \`; moving ones are enlarged ([`blocky`]).
/// Kitty frames: the first chunk (`a=T`) to the chunk with `m=0`; moving ones are
/// smaller than the pane in pixels.
fn frames(out: &[u8], log: &[(Instant, usize)], kitty: bool) -> Vec<Seen> {
    let mut v = Vec::new();
    let mut at = 0;
    let (start, full_width) = if kitty {
        (&b"\x1b_Ga=T"[..], None::<usize>)
    } else {
        (&b"\x1bP0;1;0q"[..], None)
    };
    let _ = full_width;
    while let Some(s) = find(out, start, at) {
        let end = if kitty {
            let mut e = s;
            loop {
                let Some(st) = find(out, b"\x1b\\", e + 1) else {
                    return v;
                };
                let chunk_head = &out[e..st.min(e + 200)];
                e = st + 2;
                if find(chunk_head, b"m=0", 0).is_some() {
                    break;
                }
                let Some(next) = find(out, b"\x1b_G", e) else {
                    return v;
                };
                e = next;
            }
            e
        } else {
            match find(out, b"\x1b\\", s) {
                Some(e) => e + 2,
                None => return v,
            }
        };
        let seg = &out[s..end];
        let moving = if kitty {
            let head = String::from_utf8_lossy(&seg[..seg.len().min(120)]).to_string();
            let num = |k: &str| {
                head.split(',')
                    .find_map(|kv| kv.strip_prefix(k))
                    .and_then(|v| v.parse::<u32>().ok())
                    .unwrap_or(0)
            };
            num("s=") < num("c=") * 10
        } else {
            blocky(seg)
        };
        v.push(Seen {
            bytes: end - s,
            end: arrival(log, end - 1),
            moving,
        });
        at = end;
    }
    v
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let points: u64 = args.next().map_or(Ok(2_000_000), |s| s.parse())?;
    let links: Vec<f64> = {
        let v: Vec<f64> = args.filter_map(|s| s.parse().ok()).collect();
        if v.is_empty() { vec![0.0, 10.0] } else { v }
    };
    let bin = match std::env::var_os("TERM_LINK_BIN") {
        Some(b) => std::path::PathBuf::from(b),
        None => std::env::current_exe()?
            .parent()
            .and_then(|p| p.parent())
            .map(|p| p.join("pcimg"))
            .ok_or_else(|| anyhow::anyhow!("where is the pcimg binary?"))?,
    };
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("scene.tif");
    pcimg::store::write_part(&path, &pcimg::synth::scene(points, 1), &Default::default())?;
    println!(
        "| terminal | link | probe ms | moving frame bytes (median, n) | full frame bytes (first after the keys; last) | first key → frame ms | last key → full frame ms (first full-resolution; last, exact) |"
    );
    println!("|---|---|---|---|---|---|---|");
    let terminals = [
        (
            "xterm -ti vt340 (sixel)",
            "\x1bP>|XTerm(379)\x1b\\\x1b[?63;1;2;4;6;9;15;16;22;28c",
            Kind::Sixel,
        ),
        (
            "kitty",
            "\x1bP>|kitty(0.35.2)\x1b\\\x1b_Gi=31;OK\x1b\\\x1b[?62;c",
            Kind::Kitty,
        ),
        (
            "xterm, no images (text, 24-bit)",
            "\x1bP>|XTerm(379)\x1b\\\x1b[?63;1;2;6;9;15;16;22;28c",
            Kind::Text,
        ),
    ];
    for (name, answers, kind) in terminals {
        let kitty = kind == Kind::Kitty;
        for &mbit in &links {
            let mut cmd = Command::new(&bin);
            cmd.args(["inspect", path.to_str().unwrap_or(""), "--renderer", "cpu"])
                .env_remove("TMUX")
                .env_remove("KITTY_WINDOW_ID")
                .env("TERM", "xterm-256color")
                .env("NODEVICE_SELECT", "1");
            if kind == Kind::Text {
                cmd.env("COLORTERM", "truecolor");
            } else {
                cmd.env_remove("COLORTERM");
            }
            // 194 × 44 cells: the view pane is 120 × 40, cells of 10 × 20 px.
            let mut t = Pty::spawn(&mut cmd, (194, 44), (1940, 880));
            if mbit > 0.0 {
                t.link = Some(mbit * 1e6 / 8.0);
            }
            let asked = Instant::now();
            t.read_until(Duration::from_secs(10), |o| pty::contains(o, b"\x1b[c"));
            t.write(answers.as_bytes());
            let probe_ms = asked.elapsed().as_secs_f64() * 1e3;
            // The first full frame, then quiet.
            t.read_for(Duration::from_secs(4));
            let settled = t.output.len();
            // Ten presses of `l` 50 ms apart (a held key repeats at ~20-30 Hz).
            let mut keys = Vec::new();
            for _ in 0..10 {
                keys.push(Instant::now());
                t.write(b"l");
                t.read_for(Duration::from_millis(50));
            }
            // Long enough for a reduced full frame and the exact one after it
            // at 1 Mbit/s.
            t.read_for(Duration::from_secs(if mbit > 0.0 && mbit < 5.0 {
                8
            } else {
                3
            }));
            t.write(b"q");
            t.wait(Duration::from_secs(10));
            if std::env::var_os("TERM_LINK_DUMP").is_some() {
                let k = ["sixel", "kitty", "text"][kind as usize];
                std::fs::write(format!("/tmp/term_link_{k}_{mbit}.out"), &t.output)?;
            }
            let seen: Vec<Seen> = if kind == Kind::Text {
                text_frames(&t.output, &t.log, *keys.last().unwrap_or(&keys[0]))
            } else {
                frames(&t.output, &t.log, kitty)
            }
            .into_iter()
            .filter(|f| arrival(&t.log, settled) <= f.end)
            .collect();
            let first_key = keys[0];
            if std::env::var_os("TERM_LINK_VERBOSE").is_some() {
                for f in &seen {
                    eprintln!(
                        "  {:>4} K {} at {:+.0} ms from the last key",
                        f.bytes / 1024,
                        if f.moving { "moving" } else { "full  " },
                        (f.end.duration_since(first_key).as_secs_f64()
                            - keys
                                .last()
                                .map_or(0.0, |k| k.duration_since(first_key).as_secs_f64()))
                            * 1e3
                    );
                }
            }
            let last_key = *keys.last().unwrap_or(&first_key);
            let moving: Vec<f64> = seen
                .iter()
                .filter(|f| f.moving)
                .map(|f| f.bytes as f64)
                .collect();
            let full = seen.iter().rev().find(|f| !f.moving);
            let first_full = seen.iter().find(|f| !f.moving && f.end > last_key);
            let first = seen.iter().find(|f| f.end > first_key);
            let ms = |a: Instant, b: Instant| b.saturating_duration_since(a).as_secs_f64() * 1e3;
            println!(
                "| {name} | {} | {probe_ms:.1} | {:.0} K ({}) | {} | {} | {} |",
                if mbit > 0.0 {
                    format!("{mbit} Mbit/s")
                } else {
                    "pty, unthrottled".into()
                },
                median(moving.clone()) / 1024.0,
                moving.len(),
                match (first_full, full) {
                    (Some(a), Some(b)) => format!(
                        "{:.0} K; {:.0} K",
                        a.bytes as f64 / 1024.0,
                        b.bytes as f64 / 1024.0
                    ),
                    (None, Some(b)) => format!("{:.0} K", b.bytes as f64 / 1024.0),
                    _ => "-".into(),
                },
                first.map_or("-".into(), |f| format!("{:.0}", ms(first_key, f.end))),
                match (first_full, full.filter(|f| f.end > last_key)) {
                    (Some(a), Some(b)) =>
                        format!("{:.0}; {:.0}", ms(last_key, a.end), ms(last_key, b.end)),
                    _ => "-".into(),
                },
            );
        }
    }
    Ok(())
}
