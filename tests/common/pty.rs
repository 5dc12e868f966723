//! A pseudo-terminal for tests and measurements: a program started on the pty's
//! slave side as its controlling terminal, and the test playing the terminal on
//! the master side (reading what the program writes, answering its queries,
//! typing keys), optionally draining output no faster than a given link speed.
#![allow(dead_code)]

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

pub struct Pty {
    pub master: OwnedFd,
    /// Kept open so the terminal's settings can be read after the program ends.
    pub slave: OwnedFd,
    pub child: Child,
    /// Everything read from the program so far.
    pub output: Vec<u8>,
    /// Bytes per second the "terminal" reads at (None: as fast as it comes).
    pub link: Option<f64>,
    /// The terminal's settings before the program started.
    pub initial: (u32, u32, u32, u32),
    /// When each read ended, and the output's length then.
    pub log: Vec<(Instant, usize)>,
}

/// The settings of a terminal as `tcgetattr` gives them, comparable.
pub fn termios(fd: RawFd) -> (u32, u32, u32, u32) {
    // SAFETY: tcgetattr fills the struct we pass.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::tcgetattr(fd, &mut t) }, 0);
    (t.c_iflag, t.c_oflag, t.c_cflag, t.c_lflag)
}

impl Pty {
    /// Starts `cmd` on a new pty of `cols` × `rows` cells and `px` pixels.
    pub fn spawn(cmd: &mut Command, (cols, rows): (u16, u16), px: (u16, u16)) -> Pty {
        let (mut m, mut s) = (0, 0);
        let ws = libc::winsize {
            ws_row: rows,
            ws_col: cols,
            ws_xpixel: px.0,
            ws_ypixel: px.1,
        };
        // SAFETY: openpty writes two fds; the winsize is read.
        let r =
            unsafe { libc::openpty(&mut m, &mut s, std::ptr::null_mut(), std::ptr::null(), &ws) };
        assert_eq!(r, 0, "openpty");
        // SAFETY: fresh fds from openpty, owned here.
        let master = unsafe { OwnedFd::from_raw_fd(m) };
        let slave = unsafe { OwnedFd::from_raw_fd(s) };
        let initial = termios(s);
        let io = |fd: &OwnedFd| Stdio::from(fd.try_clone().unwrap());
        cmd.stdin(io(&slave)).stdout(io(&slave)).stderr(io(&slave));
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                if libc::setsid() < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                if libc::ioctl(0, libc::TIOCSCTTY, 0) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd.spawn().expect("the program starts on the pty");
        Pty {
            master,
            slave,
            child,
            output: Vec::new(),
            link: None,
            initial,
            log: Vec::new(),
        }
    }

    /// Reads what arrives for up to `dur` (at the link's speed when set).
    pub fn read_for(&mut self, dur: Duration) -> usize {
        let end = Instant::now() + dur;
        let mut got = 0;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            got += self.read_some(left);
        }
        got
    }

    /// Reads once, waiting at most `wait`; returns the bytes read.
    pub fn read_some(&mut self, wait: Duration) -> usize {
        let fd = self.master.as_raw_fd();
        let mut p = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = wait.as_millis().clamp(0, 1000) as i32;
        // SAFETY: one valid pollfd.
        if unsafe { libc::poll(&mut p, 1, ms) } <= 0 || p.revents & libc::POLLIN == 0 {
            if p.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
                std::thread::sleep(wait.min(Duration::from_millis(5)));
            }
            return 0;
        }
        let chunk = if self.link.is_some() { 4096 } else { 65536 };
        let mut buf = vec![0u8; chunk];
        let t = Instant::now();
        // SAFETY: reading into a live buffer of its own length.
        let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
        if n <= 0 {
            return 0;
        }
        let n = n as usize;
        self.output.extend_from_slice(&buf[..n]);
        if let Some(rate) = self.link {
            // A slow link: these bytes take n / rate seconds to arrive.
            let due = Duration::from_secs_f64(n as f64 / rate);
            if let Some(rest) = due.checked_sub(t.elapsed()) {
                std::thread::sleep(rest);
            }
        }
        self.log.push((Instant::now(), self.output.len()));
        // A cursor position request (crossterm asks when ratatui starts): answered
        // as a terminal would.
        if contains(&buf[..n], b"\x1b[6n") {
            self.write(b"\x1b[1;1R");
        }
        n
    }

    /// Reads until `found(output)` holds or `timeout`; whether it held.
    pub fn read_until(&mut self, timeout: Duration, found: impl Fn(&[u8]) -> bool) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if found(&self.output) {
                return true;
            }
            self.read_some(Duration::from_millis(20));
        }
        found(&self.output)
    }

    /// Types `bytes` as the terminal would send them.
    pub fn write(&self, bytes: &[u8]) {
        let fd = self.master.as_raw_fd();
        // SAFETY: writing from a live slice.
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        assert_eq!(n, bytes.len() as isize, "write to the pty");
    }

    /// Waits for the program to end, reading its output meanwhile.
    pub fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Ok(Some(s)) = self.child.try_wait() {
                self.read_for(Duration::from_millis(20));
                return Some(s);
            }
            self.read_some(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        None
    }
}

/// Whether `hay` contains `needle`.
pub fn contains(hay: &[u8], needle: &[u8]) -> bool {
    hay.windows(needle.len()).any(|w| w == needle)
}
