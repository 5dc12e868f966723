//! Inside tmux: asking the tmux server (not the terminal through it) what the
//! outer terminal is and its cell size, and turning `allow-passthrough` on for our
//! pane only while images are sent through it, putting it back on exit.

use serde::Serialize;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How long a `tmux` command may take before we give up on it.
const TIMEOUT: Duration = Duration::from_millis(1000);

/// What the tmux server says of the client our pane is shown on.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TmuxInfo {
    /// The outer terminal's XTVERSION as tmux saw it (`kitty(0.35.2)`); empty when
    /// the outer terminal did not say (tmux 3.3 and later ask it).
    pub termtype: String,
    /// The outer terminal's `TERM` (`xterm-kitty`, `xterm-ghostty`…).
    pub termname: String,
    /// tmux's feature list for the client (`sixel` when tmux draws sixel itself).
    pub features: String,
    /// The outer terminal's cell size in pixels, when it reported one.
    pub cell_pixels: Option<(u32, u32)>,
    /// tmux's own version (`3.3a`).
    pub version: String,
    /// The pane we run in (`%3`).
    pub pane: String,
    /// Milliseconds the query took.
    pub millis: f64,
}

impl TmuxInfo {
    /// Whether tmux itself draws sixel images for this client (tmux 3.4 and
    /// later, built with sixel, on a terminal that draws sixel).
    pub(crate) fn draws_sixel(&self) -> bool {
        self.features.split(',').any(|f| f.trim() == "sixel")
    }
}

/// Runs `tmux ARGS` with a time limit; its stdout, or why it failed.
fn tmux(args: &[&str]) -> Result<String, String> {
    let mut child = Command::new("tmux")
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot run tmux: {e}"))?;
    let start = Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(_)) => break,
            Ok(None) if start.elapsed() > TIMEOUT => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("tmux did not answer within {TIMEOUT:?}"));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(1)),
            Err(e) => return Err(format!("tmux: {e}")),
        }
    }
    let out = child.wait_with_output().map_err(|e| format!("tmux: {e}"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        return Err(format!("tmux: {}", crate::text::sanitize(err.trim())));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Asks the tmux server about the client showing `pane` (`$TMUX_PANE`; the
/// current client when `None`).
pub fn query(pane: Option<&str>) -> Result<TmuxInfo, String> {
    let start = Instant::now();
    let format = "#{client_termtype}\t#{client_termname}\t#{client_termfeatures}\t\
                  #{client_cell_width}\t#{client_cell_height}\t#{version}\t#{pane_id}";
    let mut args = vec!["display-message", "-p"];
    if let Some(p) = pane {
        args.extend(["-t", p]);
    }
    args.push(format);
    let out = tmux(&args)?;
    let f: Vec<&str> = out.trim_end_matches('\n').split('\t').collect();
    if f.len() < 7 {
        return Err(format!(
            "tmux answered {:?}, not the {} fields asked for",
            crate::text::sanitize(out.trim()),
            7
        ));
    }
    let num = |s: &str| s.trim().parse::<u32>().unwrap_or(0);
    let clean = |s: &str| crate::text::sanitize(s.trim());
    Ok(TmuxInfo {
        termtype: clean(f[0]),
        termname: clean(f[1]),
        features: clean(f[2]),
        cell_pixels: super::probe::plausible_cell((num(f[3]), num(f[4]))),
        version: clean(f[5]),
        pane: clean(f[6]),
        millis: start.elapsed().as_secs_f64() * 1e3,
    })
}

/// The pane whose `allow-passthrough` we changed, and its pane-level value
/// before (`None`: it had none of its own and inherited the window's).
static CHANGED: Mutex<Option<(String, Option<String>)>> = Mutex::new(None);

/// Turns `allow-passthrough` on for `pane` only (tmux 3.3 and later), remembering
/// its own value to put back with [`restore_passthrough`].
pub fn allow_passthrough(pane: &str) -> Result<(), String> {
    let before = tmux(&["show-options", "-p", "-v", "-t", pane, "allow-passthrough"])?;
    let before = before.trim();
    if before == "on" || before == "all" {
        return Ok(());
    }
    tmux(&["set-option", "-p", "-t", pane, "allow-passthrough", "on"])?;
    if let Ok(mut c) = CHANGED.lock() {
        *c = Some((
            pane.to_string(),
            (!before.is_empty()).then(|| before.to_string()),
        ));
    }
    Ok(())
}

/// Puts back the pane's `allow-passthrough` as [`allow_passthrough`] found it
/// (once; later calls do nothing).
pub fn restore_passthrough() {
    let Some((pane, before)) = CHANGED.lock().ok().and_then(|mut c| c.take()) else {
        return;
    };
    let _ = match before {
        Some(v) => tmux(&["set-option", "-p", "-t", &pane, "allow-passthrough", &v]),
        None => tmux(&["set-option", "-p", "-u", "-t", &pane, "allow-passthrough"]),
    };
}

/// Wraps an escape sequence in tmux's passthrough (`ESC P tmux; … ESC \`, every
/// inner ESC doubled); tmux forwards it when `allow-passthrough` is on.
pub fn passthrough(seq: &str) -> String {
    let mut s = String::with_capacity(seq.len() + 16);
    s.push_str("\x1bPtmux;");
    for ch in seq.chars() {
        if ch == '\x1b' {
            s.push('\x1b');
        }
        s.push(ch);
    }
    s.push_str("\x1b\\");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passthrough_doubles_every_escape() {
        let s = passthrough("\x1bP0;1;0q#0!5~\x1b\\");
        assert_eq!(s, "\x1bPtmux;\x1b\x1bP0;1;0q#0!5~\x1b\x1b\\\x1b\\");
    }
}
