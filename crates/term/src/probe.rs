//! Asking the terminal what it is and what it draws: the queries written in one
//! go, the answers read with `poll(2)` on the tty until DA1's (the fence) or a
//! time cap, in raw mode that is put back as it was found on every path.
//!
//! No thread is started: the caller waits at most the cap. Bytes that are not
//! answers are returned as typed input (see [`super::typed`]), so a key pressed
//! during the probe still reaches the inspector.

use super::replies::{self, Replies, Scanner};
use serde::Serialize;
use std::os::fd::RawFd;
use std::time::{Duration, Instant};

/// How long to wait for a terminal that does not answer.
pub const CAP: Duration = Duration::from_millis(1000);

/// What the probe saw.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Probe {
    pub replies: Replies,
    /// Each answer as printable text, with the milliseconds since the queries
    /// were written when the read that completed it returned.
    pub answers: Vec<(f64, String)>,
    /// Milliseconds from writing the queries to the fence (or the cap).
    pub millis: f64,
    /// Whether the cap ended the wait (no DA1 answer came).
    pub capped: bool,
    /// Bytes typed during the probe (keys), for the inspector.
    #[serde(serialize_with = "as_escaped")]
    pub typed: Vec<u8>,
}

fn as_escaped<S: serde::Serializer>(bytes: &[u8], s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&replies::escaped(bytes))
}

/// The terminal's size from `TIOCGWINSZ`: cells and, where it says, pixels.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct WinSize {
    pub cols: u16,
    pub rows: u16,
    pub width_px: u16,
    pub height_px: u16,
}

impl WinSize {
    /// The size of `fd`'s terminal, if it is one.
    pub fn of(fd: RawFd) -> Option<WinSize> {
        // SAFETY: TIOCGWINSZ writes one `winsize` into the struct we pass.
        let mut ws: libc::winsize = unsafe { std::mem::zeroed() };
        // SAFETY: `ws` is a valid, writable winsize for the ioctl to fill.
        let r = unsafe { libc::ioctl(fd, libc::TIOCGWINSZ, &mut ws) };
        (r == 0).then_some(WinSize {
            cols: ws.ws_col,
            rows: ws.ws_row,
            width_px: ws.ws_xpixel,
            height_px: ws.ws_ypixel,
        })
    }

    /// Pixels per cell, when the pixel size is given and gives a plausible cell
    /// (2–64 pixels wide, 4–128 high; some terminals report nonsense or zero).
    pub fn cell_pixels(&self) -> Option<(u32, u32)> {
        if self.cols == 0 || self.rows == 0 {
            return None;
        }
        let w = self.width_px as u32 / self.cols as u32;
        let h = self.height_px as u32 / self.rows as u32;
        plausible_cell((w, h))
    }
}

/// `cell` when it could be a character cell in pixels.
pub(crate) fn plausible_cell(cell: (u32, u32)) -> Option<(u32, u32)> {
    let (w, h) = cell;
    ((2..=64).contains(&w) && (4..=128).contains(&h)).then_some(cell)
}

/// The tty's settings as found; putting them back when dropped.
struct RawMode {
    fd: RawFd,
    saved: libc::termios,
}

impl RawMode {
    fn enter(fd: RawFd) -> std::io::Result<RawMode> {
        // SAFETY: tcgetattr fills the termios we pass; cfmakeraw edits a copy.
        let mut saved: libc::termios = unsafe { std::mem::zeroed() };
        // SAFETY: `saved` is a valid termios for tcgetattr to fill.
        if unsafe { libc::tcgetattr(fd, &mut saved) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        let mut raw = saved;
        // SAFETY: cfmakeraw edits the termios we own.
        unsafe { libc::cfmakeraw(&mut raw) };
        // Keep output processing as it was: only input changes.
        raw.c_oflag = saved.c_oflag;
        // SAFETY: `raw` is a valid termios, read by tcsetattr.
        if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &raw) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(RawMode { fd, saved })
    }
}

impl Drop for RawMode {
    fn drop(&mut self) {
        // SAFETY: restoring the settings read from the same fd.
        unsafe { libc::tcsetattr(self.fd, libc::TCSANOW, &self.saved) };
    }
}

/// Writes all of `bytes` to `fd`.
fn write_all(fd: RawFd, mut bytes: &[u8]) -> std::io::Result<()> {
    while !bytes.is_empty() {
        // SAFETY: writing from a live slice of the given length.
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(e);
        }
        bytes = &bytes[n as usize..];
    }
    Ok(())
}

/// Sends the queries to `output` and reads answers from `input` (both the same
/// terminal) until DA1's answer or `cap`. Raw mode is entered on `input` for the
/// duration and left as found.
pub fn run(input: RawFd, output: RawFd, cap: Duration) -> std::io::Result<Probe> {
    let _raw = RawMode::enter(input)?;
    let start = Instant::now();
    write_all(output, replies::queries().as_bytes())?;
    let mut scanner = Scanner::default();
    let mut answers = Vec::new();
    let mut buf = [0u8; 4096];
    let mut capped = false;
    while !scanner.fenced {
        let left = cap.saturating_sub(start.elapsed());
        if left.is_zero() {
            capped = true;
            break;
        }
        let mut fd = libc::pollfd {
            fd: input,
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = left.as_millis().clamp(1, i32::MAX as u128) as i32;
        // SAFETY: one valid pollfd.
        let n = unsafe { libc::poll(&mut fd, 1, ms) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(e);
        }
        if n == 0 {
            continue;
        }
        if fd.revents & libc::POLLIN == 0 {
            // Hung up or an error, and nothing to read: nobody will answer.
            capped = true;
            break;
        }
        // SAFETY: reading into a live buffer of its own length.
        let got = unsafe { libc::read(input, buf.as_mut_ptr().cast(), buf.len()) };
        if got <= 0 {
            let e = std::io::Error::last_os_error();
            if got < 0 && e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            capped = true;
            break;
        }
        let before = scanner.answers.len();
        scanner.feed(&buf[..got as usize]);
        let at = start.elapsed().as_secs_f64() * 1e3;
        for a in &scanner.answers[before..] {
            answers.push((at, replies::escaped(a)));
        }
    }
    scanner.finish();
    Ok(Probe {
        replies: scanner.replies,
        answers,
        millis: start.elapsed().as_secs_f64() * 1e3,
        capped,
        typed: scanner.typed,
    })
}
