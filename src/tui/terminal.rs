//! Entering and leaving the inspector's terminal mode (raw input, alternate
//! screen, hidden cursor) on every exit path: a normal return, an error (the
//! [`Session`] guard's `Drop`) and a panic on any thread (a panic hook that
//! restores the terminal before the message is printed); and waiting for input in
//! a way that notices a terminal that went away.

use super::protocol;
use crossterm::cursor::{Hide, Show};
use crossterm::event::{DisableMouseCapture, EnableMouseCapture};
use crossterm::execute;
use crossterm::terminal::{
    EnterAlternateScreen, LeaveAlternateScreen, disable_raw_mode, enable_raw_mode,
};
use ratatui::Terminal;
use ratatui::backend::CrosstermBackend;
use std::io::{Stdout, Write, stdout};
use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering};

/// Whether a kitty image may be on screen (deleted when leaving).
static KITTY_IMAGE: AtomicBool = AtomicBool::new(false);
/// Whether images go through tmux's passthrough (the kitty delete must too).
static PASSTHROUGH: AtomicBool = AtomicBool::new(false);
/// Whether the terminal is in the inspector's mode now.
static ACTIVE: AtomicBool = AtomicBool::new(false);
static HOOK: Once = Once::new();

/// The terminal in the inspector's mode; dropping it restores the terminal.
pub struct Session {
    /// Dropped by the session's own `Drop` (not at all when the terminal is
    /// gone: ratatui's drop would print to it, and that print panics).
    pub terminal: std::mem::ManuallyDrop<Terminal<CrosstermBackend<Stdout>>>,
}

impl Session {
    /// Enters raw mode and the alternate screen, after installing the panic hook.
    pub fn enter(encoding: protocol::Encoding) -> anyhow::Result<Session> {
        let kitty = encoding.graphics == protocol::Graphics::Kitty;
        PASSTHROUGH.store(encoding.passthrough, Ordering::SeqCst);
        HOOK.call_once(|| {
            let previous = std::panic::take_hook();
            std::panic::set_hook(Box::new(move |info| {
                restore();
                previous(info);
            }));
        });
        KITTY_IMAGE.store(kitty, Ordering::SeqCst);
        ACTIVE.store(true, Ordering::SeqCst);
        let setup = || -> anyhow::Result<Terminal<CrosstermBackend<Stdout>>> {
            enable_raw_mode()?;
            // Mouse reports: a click in the view picks the point there.
            execute!(stdout(), EnterAlternateScreen, Hide, EnableMouseCapture)?;
            let mut t = Terminal::new(CrosstermBackend::new(stdout()))?;
            t.clear()?;
            Ok(t)
        };
        match setup() {
            Ok(terminal) => Ok(Session {
                terminal: std::mem::ManuallyDrop::new(terminal),
            }),
            Err(e) => {
                restore();
                Err(e)
            }
        }
    }
}

impl Session {
    /// Ctrl-Z: raw mode delivers it as a key, so the shell's job control is done
    /// here: the terminal is restored, the process stops itself (SIGTSTP), and once
    /// continued (`fg`) the inspector's mode is entered again and the screen
    /// cleared for a full redraw.
    pub fn suspend(&mut self) -> anyhow::Result<()> {
        restore();
        // SAFETY: raising a signal at this process; SIGTSTP's default action stops
        // it, and `raise` returns once it is continued.
        unsafe { libc::raise(libc::SIGTSTP) };
        ACTIVE.store(true, Ordering::SeqCst);
        enable_raw_mode()?;
        execute!(stdout(), EnterAlternateScreen, Hide, EnableMouseCapture)?;
        self.terminal.clear()?;
        Ok(())
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        restore();
        if !hung_up() {
            // SAFETY: dropped once, here; the field is never used after.
            unsafe { std::mem::ManuallyDrop::drop(&mut self.terminal) };
        }
    }
}

/// Leaves the inspector's mode (once; later calls do nothing): deletes the kitty
/// image, leaves the alternate screen, shows the cursor, leaves raw mode, and puts
/// tmux's `allow-passthrough` back as it was.
pub fn restore() {
    if !ACTIVE.swap(false, Ordering::SeqCst) {
        return;
    }
    let mut out = stdout();
    if KITTY_IMAGE.load(Ordering::SeqCst) {
        let passthrough = PASSTHROUGH.load(Ordering::SeqCst);
        let _ = out.write_all(protocol::kitty_delete_sequence(passthrough).as_bytes());
    }
    let _ = execute!(out, DisableMouseCapture, LeaveAlternateScreen, Show);
    let _ = disable_raw_mode();
    let _ = out.flush();
    crate::term::tmux::restore_passthrough();
}

/// Whether the terminal under stdin is gone (the SSH connection or the terminal
/// window closed), asked of `poll(2)` without waiting.
///
/// Why the event loop asks before each `crossterm::event::poll`: crossterm 0.29's
/// reader loops until a read would block, and on a terminal that hung up every read
/// returns 0 bytes at once, so it spins at full CPU and never returns. A hang-up
/// that happens while crossterm waits is caught by the signal handler instead
/// (SIGHUP; see `tui::run`).
pub fn hung_up() -> bool {
    let mut fd = libc::pollfd {
        fd: libc::STDIN_FILENO,
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd, and its count is 1; a zero timeout never blocks.
    let n = unsafe { libc::poll(&mut fd, 1, 0) };
    n > 0 && fd.revents & (libc::POLLHUP | libc::POLLERR | libc::POLLNVAL) != 0
}
