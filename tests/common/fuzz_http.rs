//! The remote reader fuzzed (issue 39: "remote responses cut or corrupted"): a
//! tiny HTTP/1.1 file server on 127.0.0.1 (std's `TcpListener`, one thread per
//! connection, keep-alive) serves a small indexed dataset the way a static
//! server with Range support does (`206` and `Content-Range`, `ETag`,
//! `If-Match`), and the case's faults change chosen answers: the status line,
//! `Content-Length` or `Content-Range` wrong or missing, the body cut short
//! (the connection then closed), bytes of it flipped, the whole object for a
//! range, the `ETag` changed, a header line garbled, a chunked body broken, or
//! the connection dropped unanswered. The client is the store's own remote
//! reader (`Dataset::open_remote` over `object_store`'s HTTP client), with one
//! retry after a millisecond and a 5 s request timeout, so a fault costs no
//! backoff; what it reads must be accepted or refused with an error naming the
//! URL, never a panic. Nothing here stalls an answer: a body shorter than its
//! declared length always ends its connection.

use pcimg::remote::Remote;
use pcimg::store::Dataset;
use pcimg::synth::Rng;
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::super::below;

/// One fault: answer number `at` of the case (0 = its first request) is
/// changed as `what` says, `arg` drawing the details.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fault {
    pub at: u32,
    pub what: u8,
    pub arg: u64,
}

/// Kinds of fault (`Fault::what` below this).
const FAULT_KINDS: u64 = 10;

/// A case's faults: none (a fifth of the cases: the dataset must then read
/// whole) to three, on its first eight answers.
pub fn faults(rng: &mut Rng) -> Vec<Fault> {
    let n = [0, 1, 1, 2, 3][below(rng, 5) as usize];
    (0..n)
        .map(|_| Fault {
            at: below(rng, 8) as u32,
            what: below(rng, FAULT_KINDS) as u8,
            arg: rng.next_u64(),
        })
        .collect()
}

/// What the server does now.
#[derive(Default)]
struct State {
    faults: Vec<Fault>,
    /// Requests answered in this case.
    requests: u32,
}

/// The server, the dataset it serves (`/ds.pcimg/...`) and the client that
/// reads it.
pub struct Server {
    pub port: u16,
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    store: Arc<dyn object_store::ObjectStore>,
}

impl Server {
    /// Serves the files of `dir/ds.pcimg` (read now) under `/ds.pcimg/`.
    pub fn start(dir: &Path) -> anyhow::Result<Server> {
        let mut files = HashMap::new();
        let mut stack = vec![dir.join("ds.pcimg")];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d)? {
                let p = e?.path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let name = p.strip_prefix(dir)?.to_string_lossy().replace('\\', "/");
                    files.insert(format!("/{name}"), std::fs::read(&p)?);
                }
            }
        }
        let files = Arc::new(files);
        let listener = TcpListener::bind("127.0.0.1:0")?;
        let port = listener.local_addr()?.port();
        let state = Arc::new(Mutex::new(State::default()));
        let stop = Arc::new(AtomicBool::new(false));
        {
            let (state, stop) = (state.clone(), stop.clone());
            std::thread::spawn(move || {
                for conn in listener.incoming() {
                    if stop.load(Ordering::SeqCst) {
                        break;
                    }
                    let Ok(conn) = conn else { continue };
                    let (state, files) = (state.clone(), files.clone());
                    std::thread::spawn(move || serve(conn, &files, &state));
                }
            });
        }
        // TLS through rustls with ring, as pcimg's own client (reqwest is
        // built without a provider; plain HTTP still asks for one).
        let _ = rustls::crypto::ring::default_provider().install_default();
        let store = object_store::http::HttpBuilder::new()
            .with_url(format!("http://127.0.0.1:{port}"))
            .with_client_options(
                object_store::ClientOptions::new()
                    .with_allow_http(true)
                    .with_timeout(Duration::from_secs(5))
                    .with_connect_timeout(Duration::from_secs(5)),
            )
            .with_retry(object_store::RetryConfig {
                backoff: object_store::BackoffConfig {
                    init_backoff: Duration::from_millis(1),
                    max_backoff: Duration::from_millis(1),
                    base: 2.0,
                },
                max_retries: 1,
                retry_timeout: Duration::from_secs(5),
            })
            .build()?;
        Ok(Server {
            port,
            state,
            stop,
            store: Arc::new(store),
        })
    }

    /// The URL of the dataset.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}/ds.pcimg", self.port)
    }

    /// The next answers get `faults`.
    pub fn begin_case(&self, faults: &[Fault]) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.faults = faults.to_vec();
        s.requests = 0;
    }

    /// Answers are healthy again, and nothing of the case stays cached.
    pub fn end_case(&self) {
        self.state
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .faults
            .clear();
        pcimg::remote::file::forget_cached(&self.url());
    }

    /// Opens the dataset by its URL (`one_part`: its first part alone, by the
    /// part's URL) and reads every level of every part and node.
    pub fn read(&self, one_part: bool) -> Result<(), String> {
        let (prefix, url) = if one_part {
            (
                "ds.pcimg/tile-0-0.tif",
                format!("{}/tile-0-0.tif", self.url()),
            )
        } else {
            ("ds.pcimg", self.url())
        };
        let remote = Arc::new(Remote::with_store(self.store.clone(), prefix, &url));
        let ds = Dataset::open_remote(remote).map_err(|e| e.to_string())?;
        super::read_dataset(&ds).map_err(|e| e.to_string())
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wakes the accepting thread, which then ends.
        let _ = TcpStream::connect(("127.0.0.1", self.port));
    }
}

/// An answer being made: its status line, headers and body.
struct Answer {
    status: String,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
    /// End the connection after it.
    close: bool,
    /// Send the body chunked, with `Transfer-Encoding: chunked`; `Some(true)`:
    /// a chunk's size line garbled.
    chunked: Option<bool>,
    /// Send nothing and end the connection.
    drop: bool,
    /// Bytes sent in place of the header block's end.
    raw_header: Option<Vec<u8>>,
}

impl Answer {
    fn set(&mut self, name: &str, value: String) {
        self.remove(name);
        self.headers.push((name.to_string(), value));
    }
    fn remove(&mut self, name: &str) {
        self.headers.retain(|(n, _)| !n.eq_ignore_ascii_case(name));
    }
    fn get(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

/// Answers the requests of one connection until it ends.
fn serve(conn: TcpStream, files: &HashMap<String, Vec<u8>>, state: &Mutex<State>) {
    let _ = conn.set_read_timeout(Some(Duration::from_secs(30)));
    let _ = conn.set_nodelay(true);
    let Ok(mut out) = conn.try_clone() else {
        return;
    };
    let mut input = BufReader::new(conn);
    loop {
        let mut line = String::new();
        match input.read_line(&mut line) {
            Ok(0) | Err(_) => return,
            Ok(_) => {}
        }
        let mut parts = line.split_whitespace();
        let (method, target) = (
            parts.next().unwrap_or("").to_string(),
            parts.next().unwrap_or("").to_string(),
        );
        let mut headers = HashMap::new();
        loop {
            let mut h = String::new();
            match input.read_line(&mut h) {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
            let h = h.trim_end();
            if h.is_empty() {
                break;
            }
            if let Some((k, v)) = h.split_once(':') {
                headers.insert(k.trim().to_ascii_lowercase(), v.trim().to_string());
            }
        }
        let mut a = answer(&method, &target, &headers, files);
        let faults: Vec<Fault> = {
            let mut s = state.lock().unwrap_or_else(|p| p.into_inner());
            let n = s.requests;
            s.requests += 1;
            s.faults.iter().filter(|f| f.at == n).copied().collect()
        };
        for f in &faults {
            apply(&mut a, f, files);
            // A faulty answer ends its connection, so that what it left
            // unread cannot spoil the next case's answers.
            a.close = true;
        }
        if a.drop {
            let _ = out.shutdown(Shutdown::Both);
            return;
        }
        if send(&mut out, &a, method == "HEAD").is_err() || a.close {
            let _ = out.flush();
            let _ = out.shutdown(Shutdown::Both);
            return;
        }
    }
}

/// The honest answer to a request.
fn answer(
    method: &str,
    target: &str,
    headers: &HashMap<String, String>,
    files: &HashMap<String, Vec<u8>>,
) -> Answer {
    let mut a = Answer {
        status: "HTTP/1.1 200 OK".into(),
        headers: Vec::new(),
        body: Vec::new(),
        close: false,
        chunked: None,
        drop: false,
        raw_header: None,
    };
    let status = |a: &mut Answer, s: &str| {
        a.status = format!("HTTP/1.1 {s}");
        a.body = s.as_bytes().to_vec();
    };
    if method != "GET" && method != "HEAD" {
        status(&mut a, "405 Method Not Allowed");
        return a;
    }
    let Some(file) = files.get(target) else {
        status(&mut a, "404 Not Found");
        return a;
    };
    let len = file.len() as u64;
    let etag = format!("\"{len:x}-fuzz\"");
    a.set("ETag", etag.clone());
    a.set("Last-Modified", "Fri, 27 Nov 2026 12:00:00 GMT".into());
    a.set("Accept-Ranges", "bytes".into());
    a.set("Content-Type", "application/octet-stream".into());
    if headers
        .get("if-match")
        .is_some_and(|m| *m != etag && m != "*")
    {
        status(&mut a, "412 Precondition Failed");
        return a;
    }
    if headers.get("if-none-match").is_some_and(|m| *m == etag) {
        a.status = "HTTP/1.1 304 Not Modified".into();
        return a;
    }
    let range = headers
        .get("range")
        .and_then(|r| r.strip_prefix("bytes="))
        .and_then(|r| r.split_once('-'))
        .map(|(s, e)| (s.trim().parse::<u64>().ok(), e.trim().parse::<u64>().ok()));
    let (start, end) = match range {
        None => {
            a.body = file.clone();
            return a;
        }
        Some((Some(s), Some(e))) => (s, e.min(len.saturating_sub(1))),
        Some((Some(s), None)) => (s, len.saturating_sub(1)),
        Some((None, Some(n))) => (len.saturating_sub(n), len.saturating_sub(1)),
        Some((None, None)) => (1, 0),
    };
    if start >= len || start > end {
        status(&mut a, "416 Range Not Satisfiable");
        a.set("Content-Range", format!("bytes */{len}"));
        return a;
    }
    a.status = "HTTP/1.1 206 Partial Content".into();
    a.set("Content-Range", format!("bytes {start}-{end}/{len}"));
    a.body = file[start as usize..=end as usize].to_vec();
    a
}

/// Status lines a fault may put in place of the answer's.
const STATUS: [&str; 16] = [
    "HTTP/1.1 500 Internal Server Error",
    "HTTP/1.1 503 Slow Down",
    "HTTP/1.1 429 Too Many Requests",
    "HTTP/1.1 404 Not Found",
    "HTTP/1.1 403 Forbidden",
    "HTTP/1.1 401 Unauthorized",
    "HTTP/1.1 416 Range Not Satisfiable",
    "HTTP/1.1 304 Not Modified",
    "HTTP/1.1 412 Precondition Failed",
    "HTTP/1.1 200 OK",
    "HTTP/1.1 206 Partial Content",
    "HTTP/1.1 302 Found",
    "HTTP/1.1 204 No Content",
    "HTTP/1.1 999 Odd",
    "HTTP/1.0 200 OK",
    "HTPT/1.1 20x what",
];

/// Changes an answer as the fault says.
fn apply(a: &mut Answer, f: &Fault, files: &HashMap<String, Vec<u8>>) {
    let mut r = Rng::new(f.arg);
    let len = a.body.len() as u64;
    match f.what {
        // The status line.
        0 => a.status = STATUS[below(&mut r, STATUS.len() as u64) as usize].to_string(),
        // Content-Length wrong, missing or not a number (the body then ends
        // with the connection).
        1 => {
            a.close = true;
            let v = match below(&mut r, 6) {
                0 => Some((len + 1 + below(&mut r, 100)).to_string()),
                1 => Some(
                    len.saturating_sub(1 + below(&mut r, len.max(1)))
                        .to_string(),
                ),
                2 => None,
                3 => Some("abc".into()),
                4 => Some("-1".into()),
                _ => Some("99999999999999999999".into()),
            };
            match v {
                Some(v) => a.set("Content-Length", v),
                None => a.remove("Content-Length"),
            }
        }
        // Content-Range wrong, missing or garbled.
        2 => {
            let cr = a.get("Content-Range").unwrap_or("bytes 0-0/1").to_string();
            let nums: Vec<u64> = cr
                .trim_start_matches("bytes ")
                .split(['-', '/'])
                .map(|s| s.parse().unwrap_or(0))
                .collect();
            let (s, e, t) = (
                nums.first().copied().unwrap_or(0),
                nums.get(1).copied().unwrap_or(0),
                nums.get(2).copied().unwrap_or(0),
            );
            let v = match below(&mut r, 9) {
                0 => Some(format!("bytes {}-{e}/{t}", s + 1)),
                1 => Some(format!("bytes {s}-{}/{t}", e.saturating_sub(1))),
                2 => Some(format!("bytes {s}-{e}/{}", t + 1)),
                3 => Some(format!("bytes {s}-{e}/{}", t.saturating_sub(1))),
                4 => Some(format!("bytes {s}-{e}/*")),
                5 => Some(format!("bytes */{t}")),
                6 => Some("bytes x-y/z".into()),
                7 => Some(format!("bytes {e}-{s}/{t}")),
                _ => None,
            };
            match v {
                Some(v) => a.set("Content-Range", v),
                None => a.remove("Content-Range"),
            }
        }
        // The body cut short; the connection ends there.
        3 => {
            a.body.truncate(below(&mut r, len.max(1)) as usize);
            a.set("Content-Length", len.to_string());
            a.close = true;
        }
        // Bytes of the body flipped.
        4 => {
            if !a.body.is_empty() {
                for _ in 0..1 + below(&mut r, 8) {
                    let i = below(&mut r, len) as usize;
                    a.body[i] ^= 1 + below(&mut r, 255) as u8;
                }
            }
        }
        // No answer at all.
        5 => a.drop = true,
        // The ETag changed, missing or weak; Last-Modified garbled.
        6 => match below(&mut r, 4) {
            0 => a.set("ETag", format!("\"other-{}\"", below(&mut r, 1000))),
            1 => a.remove("ETag"),
            2 => a.set("ETag", "W/\"weak\"".into()),
            _ => a.set("Last-Modified", "yesterday".into()),
        },
        // A header line garbled, or the header block ended wrongly.
        7 => match below(&mut r, 4) {
            0 => a.headers.push(("X-Fuzz\u{7f}".into(), "\u{1}\u{2}".into())),
            1 => a.headers.push(("X-Long".into(), "x".repeat(16 << 10))),
            2 => a.raw_header = Some(b"\r\nnot a header\r\n\r\n".to_vec()),
            _ => a.raw_header = Some(b"\n\n".to_vec()),
        },
        // A chunked body, or a chunk's size line garbled.
        8 => {
            a.remove("Content-Length");
            a.chunked = Some(below(&mut r, 2) == 0);
            a.close = true;
        }
        // The whole object, or another file, in place of the range.
        _ => {
            if a.status.contains(" 206 ") {
                let mut names: Vec<&String> = files.keys().collect();
                names.sort();
                let whole = files[names[below(&mut r, names.len() as u64) as usize]].clone();
                a.status = "HTTP/1.1 200 OK".into();
                a.remove("Content-Range");
                a.body = whole;
            } else {
                a.status = "HTTP/1.1 206 Partial Content".into();
                a.set(
                    "Content-Range",
                    format!("bytes 0-{}/{len}", len.saturating_sub(1)),
                );
            }
        }
    }
}

/// Writes an answer (`head`: without its body).
fn send(out: &mut TcpStream, a: &Answer, head: bool) -> std::io::Result<()> {
    let mut w = Vec::with_capacity(a.body.len() + 512);
    w.extend_from_slice(a.status.as_bytes());
    w.extend_from_slice(b"\r\n");
    let mut has_length = false;
    for (k, v) in &a.headers {
        has_length |= k.eq_ignore_ascii_case("Content-Length");
        w.extend_from_slice(format!("{k}: {v}\r\n").as_bytes());
    }
    let chunked = a.chunked.is_some();
    if chunked {
        w.extend_from_slice(b"Transfer-Encoding: chunked\r\n");
    } else if !has_length && !a.close {
        w.extend_from_slice(format!("Content-Length: {}\r\n", a.body.len()).as_bytes());
    }
    if a.close {
        w.extend_from_slice(b"Connection: close\r\n");
    }
    match &a.raw_header {
        Some(raw) => w.extend_from_slice(raw),
        None => w.extend_from_slice(b"\r\n"),
    }
    if !head {
        match a.chunked {
            None => w.extend_from_slice(&a.body),
            Some(garbled) => {
                for (i, c) in a.body.chunks(1000).enumerate() {
                    if garbled && i == 0 {
                        w.extend_from_slice(b"zz\r\n");
                    } else {
                        w.extend_from_slice(format!("{:x}\r\n", c.len()).as_bytes());
                    }
                    w.extend_from_slice(c);
                    w.extend_from_slice(b"\r\n");
                }
                w.extend_from_slice(b"0\r\n\r\n");
            }
        }
    }
    out.write_all(&w)
}
