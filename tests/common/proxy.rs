//! A fault-injecting HTTP proxy for the tests and `examples/fault_proxy.rs`
//! (issue 39): it listens on a free port of 127.0.0.1 and passes each request
//! to an upstream server (`python3 -m http.server`, SeaweedFS's S3 port),
//! unless the schedule the test sets says otherwise: add latency, reset the
//! connection (an RST, not a clean close), answer 500 or 503 with S3's
//! `SlowDown` XML, send the response head with the full `Content-Length` but
//! only the first N bytes of the body and close, or hold the connection
//! without answering. It counts requests, faults and body bytes passed, and
//! logs each request line with what was done to it, so that tests can assert
//! that something was fetched again.
//!
//! Every response carries `Connection: close` and the connection is closed
//! after it, so each request has a connection of its own (a client then never
//! reuses one the proxy closed): request and response framing is parsed only
//! to find where a message ends (`Content-Length`, chunked, or the end of the
//! connection). Standard library and threads only.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What the proxy does to a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Forward it and its answer.
    Pass,
    /// Wait this long, then forward it.
    Delay(Duration),
    /// Close the connection with an RST without answering.
    Reset,
    /// Answer HTTP 500 (S3's `InternalError`).
    Status500,
    /// Answer HTTP 503 with S3's `SlowDown` XML.
    SlowDown,
    /// Forward it, then send the answer's head (with its full length) and
    /// only the first N bytes of its body, and close.
    Short(u64),
    /// Hold the connection without answering (until the client gives up or
    /// the proxy stops).
    Stall,
}

impl Fault {
    /// `pass`, `delay:MS`, `reset`, `500`, `503`/`slowdown`, `short:N`, `stall`.
    pub fn parse(s: &str) -> Result<Fault, String> {
        let (name, arg) = s.split_once(':').unwrap_or((s, ""));
        let num = || {
            arg.parse::<u64>()
                .map_err(|_| format!("{s}: give a number after ':'"))
        };
        Ok(match name {
            "pass" => Fault::Pass,
            "delay" | "latency" => Fault::Delay(Duration::from_millis(num()?)),
            "reset" => Fault::Reset,
            "500" => Fault::Status500,
            "503" | "slowdown" => Fault::SlowDown,
            "short" => Fault::Short(num()?),
            "stall" => Fault::Stall,
            _ => {
                return Err(format!(
                    "{s}: not a fault (pass, delay:MS, reset, 500, 503, short:N, stall)"
                ));
            }
        })
    }
}

/// One entry of the schedule: `fault` for the requests whose request line
/// (`GET /bucket/part.tif HTTP/1.1`) contains `matching`, after the first
/// `after` of them, for at most `times` of them (all where `None`).
#[derive(Debug, Clone)]
pub struct Rule {
    pub fault: Fault,
    pub matching: String,
    pub after: u64,
    pub times: Option<u64>,
    /// Matching requests seen so far.
    seen: u64,
}

impl Rule {
    /// `fault` for every request.
    pub fn new(fault: Fault) -> Rule {
        Rule {
            fault,
            matching: String::new(),
            after: 0,
            times: None,
            seen: 0,
        }
    }

    /// Only requests whose request line contains `s` (`"GET "`, `"part-0"`).
    pub fn matching(mut self, s: &str) -> Rule {
        self.matching = s.to_string();
        self
    }

    /// Not the first `n` matching requests.
    pub fn after(mut self, n: u64) -> Rule {
        self.after = n;
        self
    }

    /// At most `n` matching requests (then they pass).
    pub fn times(mut self, n: u64) -> Rule {
        self.times = Some(n);
        self
    }
}

/// A request the proxy saw: its request line, what it did, and the response
/// body bytes it sent back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seen {
    pub line: String,
    pub fault: Fault,
    pub body_bytes: u64,
}

struct State {
    upstream: SocketAddr,
    rules: Mutex<Vec<Rule>>,
    requests: AtomicU64,
    faults: AtomicU64,
    bytes: AtomicU64,
    log: Mutex<Vec<Seen>>,
    stop: AtomicBool,
}

/// The proxy; stopped (its connections closed, held ones released) on drop.
pub struct Proxy {
    pub addr: SocketAddr,
    state: Arc<State>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Proxy {
    /// Listens on a free port of 127.0.0.1 (ready when this returns: the
    /// socket is bound and listening), forwarding to `upstream`.
    pub fn start(upstream: SocketAddr) -> Proxy {
        Proxy::start_on(upstream, 0)
    }

    /// As [`Proxy::start`], on `port` (0: a free one).
    pub fn start_on(upstream: SocketAddr, port: u16) -> Proxy {
        let listener = TcpListener::bind(("127.0.0.1", port)).expect("cannot listen on 127.0.0.1");
        let addr = listener.local_addr().unwrap();
        let state = Arc::new(State {
            upstream,
            rules: Mutex::new(Vec::new()),
            requests: AtomicU64::new(0),
            faults: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
            log: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
        });
        let st = state.clone();
        std::thread::spawn(move || {
            for conn in listener.incoming() {
                if st.stop.load(Ordering::Relaxed) {
                    break;
                }
                let Ok(conn) = conn else { continue };
                let st = st.clone();
                std::thread::spawn(move || serve(conn, &st));
            }
        });
        Proxy { addr, state }
    }

    pub fn port(&self) -> u16 {
        self.addr.port()
    }

    /// `http://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Replaces the schedule (an empty one passes everything).
    pub fn set(&self, rules: Vec<Rule>) {
        *lock(&self.state.rules) = rules;
    }

    /// Requests seen.
    pub fn requests(&self) -> u64 {
        self.state.requests.load(Ordering::Relaxed)
    }

    /// Requests a fault other than `Pass` was applied to.
    pub fn faults(&self) -> u64 {
        self.state.faults.load(Ordering::Relaxed)
    }

    /// Response body bytes sent back to clients.
    pub fn bytes(&self) -> u64 {
        self.state.bytes.load(Ordering::Relaxed)
    }

    /// Every request seen, in order.
    pub fn log(&self) -> Vec<Seen> {
        lock(&self.state.log).clone()
    }

    /// Requests whose request line contains `s`.
    pub fn count(&self, s: &str) -> usize {
        lock(&self.state.log)
            .iter()
            .filter(|r| r.line.contains(s))
            .count()
    }

    /// Clears the counters and the log (the schedule stays).
    pub fn reset_counters(&self) {
        self.state.requests.store(0, Ordering::Relaxed);
        self.state.faults.store(0, Ordering::Relaxed);
        self.state.bytes.store(0, Ordering::Relaxed);
        lock(&self.state.log).clear();
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.state.stop.store(true, Ordering::Relaxed);
        // Wakes the accepting thread so that it sees `stop`.
        let _ = TcpStream::connect_timeout(&self.addr, Duration::from_millis(200));
    }
}

impl State {
    /// The fault for a request line, by the schedule (the first rule that
    /// takes it).
    fn choose(&self, line: &str) -> Fault {
        let mut rules = lock(&self.rules);
        for r in rules.iter_mut() {
            if !line.contains(&r.matching) {
                continue;
            }
            r.seen += 1;
            let k = r.seen;
            if k > r.after && r.times.is_none_or(|t| k - r.after <= t) {
                return r.fault;
            }
        }
        Fault::Pass
    }
}

/// An HTTP message head: its bytes (up to and with the blank line) and parsed
/// first line and headers.
struct Head {
    first: String,
    headers: Vec<(String, String)>,
}

impl Head {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    fn chunked(&self) -> bool {
        self.header("transfer-encoding")
            .is_some_and(|v| v.to_ascii_lowercase().contains("chunked"))
    }

    fn length(&self) -> Option<u64> {
        self.header("content-length")
            .and_then(|v| v.trim().parse().ok())
    }

    /// The head again, its `Connection` headers replaced by `close`.
    fn closing(&self) -> Vec<u8> {
        let mut out = format!("{}\r\n", self.first);
        for (k, v) in &self.headers {
            if k.eq_ignore_ascii_case("connection") || k.eq_ignore_ascii_case("keep-alive") {
                continue;
            }
            out.push_str(&format!("{k}: {v}\r\n"));
        }
        out.push_str("Connection: close\r\n\r\n");
        out.into_bytes()
    }
}

/// Reads a message head; `None` at the end of the stream (or on an error).
fn read_head(r: &mut impl BufRead) -> Option<Head> {
    let mut first = String::new();
    loop {
        first.clear();
        if r.read_line(&mut first).ok()? == 0 {
            return None;
        }
        // (Blank lines before a request are allowed.)
        if !first.trim().is_empty() {
            break;
        }
    }
    let mut headers = Vec::new();
    loop {
        let mut line = String::new();
        if r.read_line(&mut line).ok()? == 0 {
            return None;
        }
        let line = line.trim_end_matches(['\r', '\n']);
        if line.is_empty() {
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            headers.push((k.trim().to_string(), v.trim().to_string()));
        }
    }
    Some(Head {
        first: first.trim_end_matches(['\r', '\n']).to_string(),
        headers,
    })
}

/// A message body as it came (chunked framing kept): by `Content-Length`, by
/// chunks, or (`to_end`) up to the end of the stream.
fn read_body(r: &mut impl BufRead, head: &Head, to_end: bool) -> std::io::Result<Vec<u8>> {
    let mut body = Vec::new();
    if head.chunked() {
        loop {
            let mut size_line = String::new();
            if r.read_line(&mut size_line)? == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            body.extend_from_slice(size_line.as_bytes());
            let hex = size_line.trim().split(';').next().unwrap_or("");
            let size = u64::from_str_radix(hex, 16)
                .map_err(|_| std::io::Error::other(format!("bad chunk size {hex:?}")))?;
            if size == 0 {
                // Trailers, up to the blank line.
                loop {
                    let mut t = String::new();
                    if r.read_line(&mut t)? == 0 {
                        return Ok(body);
                    }
                    body.extend_from_slice(t.as_bytes());
                    if t.trim().is_empty() {
                        return Ok(body);
                    }
                }
            }
            let at = body.len();
            body.resize(at + size as usize + 2, 0);
            r.read_exact(&mut body[at..])?;
        }
    }
    match head.length() {
        Some(n) => {
            body.resize(n as usize, 0);
            r.read_exact(&mut body)?;
        }
        None if to_end => {
            r.read_to_end(&mut body)?;
        }
        None => {}
    }
    Ok(body)
}

/// Closes `s` with an RST (SO_LINGER 0), not a clean FIN.
fn reset(s: TcpStream) {
    use std::os::fd::AsRawFd;
    let linger = libc::linger {
        l_onoff: 1,
        l_linger: 0,
    };
    // SAFETY: a valid socket of ours and a properly sized option value.
    unsafe {
        libc::setsockopt(
            s.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_LINGER,
            (&linger as *const libc::linger).cast(),
            std::mem::size_of::<libc::linger>() as libc::socklen_t,
        );
    }
    drop(s);
}

/// An answer made by the proxy itself.
fn answer(client: &mut TcpStream, status: &str, body: &str) {
    let _ = write!(
        client,
        "HTTP/1.1 {status}\r\nContent-Type: application/xml\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = client.flush();
}

/// One client connection: one request (every answer closes it).
fn serve(mut client: TcpStream, st: &State) {
    let Ok(read_half) = client.try_clone() else {
        return;
    };
    let mut reader = BufReader::new(read_half);
    let Some(head) = read_head(&mut reader) else {
        return;
    };
    let Ok(body) = read_body(&mut reader, &head, false) else {
        return;
    };
    st.requests.fetch_add(1, Ordering::Relaxed);
    let fault = st.choose(&head.first);
    if fault != Fault::Pass {
        st.faults.fetch_add(1, Ordering::Relaxed);
    }
    let path = head.first.split(' ').nth(1).unwrap_or("/").to_string();
    match fault {
        Fault::Reset => {
            log(st, &head.first, fault, 0);
            reset(client);
            return;
        }
        Fault::Stall => {
            log(st, &head.first, fault, 0);
            let _ = client.set_read_timeout(Some(Duration::from_millis(50)));
            let mut buf = [0u8; 4096];
            while !st.stop.load(Ordering::Relaxed) {
                match client.read(&mut buf) {
                    Ok(0) => return,
                    Ok(_) => {}
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) => {}
                    Err(_) => return,
                }
            }
            return;
        }
        Fault::Status500 => {
            log(st, &head.first, fault, 0);
            answer(
                &mut client,
                "500 Internal Server Error",
                &format!(
                    "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Error><Code>InternalError</Code><Message>We encountered an internal error. Please try again.</Message><Resource>{path}</Resource><RequestId>fault-proxy</RequestId></Error>"
                ),
            );
            let _ = client.shutdown(Shutdown::Both);
            return;
        }
        Fault::SlowDown => {
            log(st, &head.first, fault, 0);
            answer(
                &mut client,
                "503 Slow Down",
                &format!(
                    "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Error><Code>SlowDown</Code><Message>Please reduce your request rate.</Message><Resource>{path}</Resource><RequestId>fault-proxy</RequestId></Error>"
                ),
            );
            let _ = client.shutdown(Shutdown::Both);
            return;
        }
        Fault::Delay(d) => std::thread::sleep(d),
        Fault::Pass | Fault::Short(_) => {}
    }
    // Forwarded: the request on a connection of its own, then the answer.
    let Ok(mut up) = TcpStream::connect(st.upstream) else {
        log(st, &head.first, fault, 0);
        reset(client);
        return;
    };
    let mut out = head.closing();
    out.extend_from_slice(&body);
    if up.write_all(&out).and_then(|()| up.flush()).is_err() {
        log(st, &head.first, fault, 0);
        reset(client);
        return;
    }
    let is_head = head.first.starts_with("HEAD ");
    let mut upr = BufReader::new(up);
    let answer_head = loop {
        let Some(h) = read_head(&mut upr) else {
            log(st, &head.first, fault, 0);
            reset(client);
            return;
        };
        // (An interim 1xx answer: the real one follows.)
        if !h
            .first
            .split(' ')
            .nth(1)
            .is_some_and(|c| c.starts_with('1'))
        {
            break h;
        }
    };
    let status = answer_head.first.split(' ').nth(1).unwrap_or("");
    let bodiless = is_head || status == "204" || status == "304";
    let answer_body = if bodiless {
        Vec::new()
    } else {
        match read_body(&mut upr, &answer_head, true) {
            Ok(b) => b,
            Err(_) => {
                log(st, &head.first, fault, 0);
                reset(client);
                return;
            }
        }
    };
    let shown = match fault {
        Fault::Short(n) => &answer_body[..(n as usize).min(answer_body.len())],
        _ => &answer_body[..],
    };
    let mut msg = answer_head.closing();
    msg.extend_from_slice(shown);
    // Counted before it is sent: the client may finish, and the test count,
    // before this thread runs again after the write.
    let sent = shown.len() as u64;
    st.bytes.fetch_add(sent, Ordering::Relaxed);
    log(st, &head.first, fault, sent);
    let _ = client.write_all(&msg).and_then(|()| client.flush());
    let _ = client.shutdown(Shutdown::Both);
}

fn log(st: &State, line: &str, fault: Fault, body_bytes: u64) {
    lock(&st.log).push(Seen {
        line: line.to_string(),
        fault,
        body_bytes,
    });
}
