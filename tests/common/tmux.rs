//! tmux on a private socket for tests: commands against it, the pane's text, and
//! the server killed when dropped.
#![allow(dead_code)]

use std::process::Command;
use std::time::{Duration, Instant};

pub struct Tmux {
    pub socket: String,
}

impl Tmux {
    /// A server of its own for this process and `name`.
    pub fn new(name: &str) -> Tmux {
        Tmux {
            socket: format!("pcimg-{name}-{}", std::process::id()),
        }
    }

    /// `tmux` on this server, with no config and not inside the caller's tmux.
    pub fn cmd(&self) -> Command {
        let mut c = Command::new("tmux");
        c.args(["-L", &self.socket, "-f", "/dev/null"]);
        c.env_remove("TMUX");
        c
    }

    /// Runs a tmux command that must succeed; its stdout.
    pub fn run(&self, args: &[&str]) -> String {
        let o = self.cmd().args(args).output().expect("tmux runs");
        assert!(
            o.status.success(),
            "tmux {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8_lossy(&o.stdout).into_owned()
    }

    /// A 120 × 40 session `t` running `command`.
    pub fn start(&self, command: &str) {
        self.session((120, 40), &[command]);
    }

    /// A session `t` of `size` running `command` (a program and its arguments).
    fn session(&self, size: (u16, u16), command: &[&str]) {
        let (x, y) = (size.0.to_string(), size.1.to_string());
        let mut args = vec!["new-session", "-d", "-s", "t", "-x", &x, "-y", &y];
        args.extend_from_slice(command);
        self.run(&args);
    }

    /// Starts a shell in a `size` window and types `pcimg inspect PATH
    /// --renderer cpu EXTRA` into it.
    pub fn inspect(&self, size: (u16, u16), path: &std::path::Path, extra: &str) {
        self.session(size, &["env", "PS1=$ ", "sh"]);
        let line = format!(
            "NODEVICE_SELECT=1 '{}' inspect '{}' --renderer cpu {extra}",
            env!("CARGO_BIN_EXE_pcimg"),
            path.display()
        );
        self.run(&["send-keys", "-t", "t", "-l", &line]);
        self.run(&["send-keys", "-t", "t", "Enter"]);
    }

    pub fn capture(&self) -> String {
        self.run(&["capture-pane", "-p", "-t", "t"])
    }

    /// Polls the pane until `pred` holds, at most `secs` seconds.
    pub fn wait_for(&self, what: &str, secs: u64, pred: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + Duration::from_secs(secs);
        loop {
            let s = self.capture();
            if pred(&s) {
                return s;
            }
            assert!(
                Instant::now() < deadline,
                "waited {secs} s for {what}; the pane shows:\n{s}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.cmd().arg("kill-server").output();
    }
}
