//! Entering and leaving the inspector's terminal mode (raw input, alternate
//! screen, hidden cursor) on every exit path: a normal return, an error (the
//! [`Session`] guard's `Drop`) and a panic on any thread (a panic hook that
//! restores the terminal before the message is printed).

use super::protocol;
use crossterm::cursor::{Hide, Show};
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
/// Whether the terminal is in the inspector's mode now.
static ACTIVE: AtomicBool = AtomicBool::new(false);
static HOOK: Once = Once::new();

/// The terminal in the inspector's mode; dropping it restores the terminal.
pub struct Session {
    pub terminal: Terminal<CrosstermBackend<Stdout>>,
}

impl Session {
    /// Enters raw mode and the alternate screen, after installing the panic hook.
    pub fn enter(kitty: bool) -> anyhow::Result<Session> {
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
            execute!(stdout(), EnterAlternateScreen, Hide)?;
            let mut t = Terminal::new(CrosstermBackend::new(stdout()))?;
            t.clear()?;
            Ok(t)
        };
        match setup() {
            Ok(terminal) => Ok(Session { terminal }),
            Err(e) => {
                restore();
                Err(e)
            }
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        restore();
    }
}

/// Leaves the inspector's mode (once; later calls do nothing): deletes the kitty
/// image, leaves the alternate screen, shows the cursor, leaves raw mode.
pub fn restore() {
    if !ACTIVE.swap(false, Ordering::SeqCst) {
        return;
    }
    let mut out = stdout();
    if KITTY_IMAGE.load(Ordering::SeqCst) {
        let _ = out.write_all(protocol::kitty_delete_sequence().as_bytes());
    }
    let _ = execute!(out, LeaveAlternateScreen, Show);
    let _ = disable_raw_mode();
    let _ = out.flush();
}
