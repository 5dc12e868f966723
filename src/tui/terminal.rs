//! Entering and leaving the inspector's terminal mode (raw input, alternate
//! screen, hidden cursor) on every exit path: a normal return, an error (the
//! [`Session`] guard's `Drop`) and a panic on any thread (a panic hook that
//! restores the terminal before the message is printed), and a hang-up (the
//! [`spawn_watchdog`] thread).

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

/// crossterm 0.29's event reader spins without end inside `poll` once its
/// terminal is gone (a hung-up pty reads 0 bytes, which `event/source/unix/mio.rs`
/// retries forever), so after an SSH drop or a killed tmux pane the event loop
/// never sees `stop` again and the process burns a core. This thread notices a
/// hang-up (`stop` set by SIGHUP/SIGTERM, or the terminal failing `tcgetattr`)
/// and, when the event loop has not ended within a second, restores what it can
/// and exits with status 129. It ends by itself when the session ends.
pub fn spawn_watchdog(stop: &'static AtomicBool) {
    #[cfg(unix)]
    let watched_fd = {
        // SAFETY: isatty only inspects the descriptor.
        (unsafe { libc::isatty(0) } == 1).then_some(0)
    };
    #[cfg(not(unix))]
    let watched_fd: Option<i32> = None;
    let _ = std::thread::Builder::new()
        .name("pcimg-watchdog".into())
        .spawn(move || {
            let mut stopping: Option<std::time::Instant> = None;
            loop {
                std::thread::sleep(std::time::Duration::from_millis(200));
                if !ACTIVE.load(Ordering::SeqCst) {
                    return;
                }
                if watched_fd.is_some_and(terminal_gone) {
                    stop.store(true, Ordering::SeqCst);
                }
                if stop.load(Ordering::SeqCst) {
                    let since = *stopping.get_or_insert_with(std::time::Instant::now);
                    if since.elapsed() > std::time::Duration::from_secs(1) {
                        restore();
                        std::process::exit(129);
                    }
                }
            }
        });
}

/// Whether the terminal on `fd` no longer answers (hung up or closed).
#[cfg(unix)]
fn terminal_gone(fd: i32) -> bool {
    let mut t = std::mem::MaybeUninit::<libc::termios>::uninit();
    // SAFETY: tcgetattr writes the termios it is given, or fails.
    unsafe { libc::tcgetattr(fd, t.as_mut_ptr()) != 0 }
}

#[cfg(not(unix))]
fn terminal_gone(_: i32) -> bool {
    false
}
