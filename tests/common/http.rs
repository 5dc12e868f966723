//! A static file server for tests, started the way a user starts one:
//! `python3 -m http.server` on a free port of 127.0.0.1, waited for by
//! connecting, killed and reaped on drop. It can be stopped and started again
//! on the same port (a server that goes away and returns).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub struct HttpServer {
    child: Option<Child>,
    pub port: u16,
    dir: PathBuf,
}

impl Drop for HttpServer {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A TCP port of 127.0.0.1 that nothing listens on (as chosen).
pub fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// Whether something accepts connections at 127.0.0.1:`port`.
pub fn listening(port: u16) -> bool {
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    std::net::TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_ok()
}

impl HttpServer {
    /// Serves `dir` on a free port, and returns once the port accepts
    /// connections. `None` (outside CI) when python3 is missing.
    pub fn start(dir: &Path) -> Option<HttpServer> {
        if !super::tool_available("python3", "--version") {
            return None;
        }
        let mut s = HttpServer {
            child: None,
            port: free_port(),
            dir: dir.to_path_buf(),
        };
        s.restart();
        Some(s)
    }

    /// Starts the server again on its port (it must be stopped), and returns
    /// once the port accepts connections (at most 30 s).
    pub fn restart(&mut self) {
        assert!(self.child.is_none(), "the server is running");
        let child = Command::new("python3")
            .args(["-m", "http.server", "--bind", "127.0.0.1"])
            .arg(self.port.to_string())
            .arg("--directory")
            .arg(&self.dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("cannot start python3 -m http.server");
        let child = self.child.insert(child);
        let start = Instant::now();
        while !listening(self.port) {
            if let Some(status) = child.try_wait().unwrap() {
                let mut log = String::new();
                if let Some(mut e) = child.stderr.take() {
                    let _ = std::io::Read::read_to_string(&mut e, &mut log);
                }
                panic!("python3 -m http.server exited ({status}) before serving:\n{log}");
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "python3 -m http.server did not accept connections within 30 s"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Kills the server and waits until it is gone: the port refuses
    /// connections from then on.
    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    pub fn addr(&self) -> std::net::SocketAddr {
        std::net::SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    pub fn url(&self, name: &str) -> String {
        format!("http://127.0.0.1:{}/{name}", self.port)
    }
}

pub use super::cli::pcimg;

/// A synthetic scan of `points` points converted into `dir/NAME` under a
/// 1 MiB budget: several parts, an overview above them, an index.
pub fn scan_dataset(dir: &Path, name: &str, points: u64) -> PathBuf {
    let scan = dir.join("scan.las");
    let run = |c: &mut Command, what: &str| {
        let o = c.output().unwrap();
        assert!(
            o.status.success(),
            "{what} failed:\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    run(
        pcimg()
            .args(["synth", "-n", &points.to_string(), "-o"])
            .arg(&scan),
        "pcimg synth",
    );
    let out = dir.join(name);
    run(
        pcimg()
            .args(["convert", "-q", "--memory", "1MiB", "--compression", "zstd"])
            .arg(&scan)
            .arg("-o")
            .arg(&out),
        "pcimg convert",
    );
    std::fs::remove_file(&scan).unwrap();
    out
}
