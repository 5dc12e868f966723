//! The tests' fault-injecting HTTP proxy (`tests/common/proxy.rs`) as a
//! program, for `bench/faults.sh`: it forwards 127.0.0.1:PORT to an upstream
//! port, applying one fault to the requests that match, and keeps its
//! counters in a file.
//!
//! ```text
//! cargo run --example fault_proxy -- UPSTREAM_PORT FAULT [--port P]
//!     [--matching TEXT] [--after N] [--times N] [--stats FILE]
//! ```
//! FAULT: `pass`, `delay:MS`, `reset`, `500`, `503` (S3 SlowDown), `short:N`
//! (the first N body bytes, then close), `stall`. It prints the port it
//! listens on, then runs until killed; `--stats FILE` is rewritten after
//! every request: `requests=N faults=N bytes=N` (response body bytes sent).

#[allow(dead_code)]
#[path = "../tests/common/proxy.rs"]
mod proxy;

use proxy::{Fault, Proxy, Rule};
use std::io::Write;

fn main() {
    if let Err(e) = run() {
        eprintln!("fault_proxy: {e}");
        std::process::exit(2);
    }
}

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: fault_proxy UPSTREAM_PORT FAULT [--port P] [--matching TEXT] \
                 [--after N] [--times N] [--stats FILE]";
    let [upstream, fault, rest @ ..] = args.as_slice() else {
        return Err(usage.into());
    };
    let upstream: u16 = upstream.parse().map_err(|_| usage.to_string())?;
    let mut rule = Rule::new(Fault::parse(fault)?);
    let (mut port, mut stats) = (0u16, None);
    let mut it = rest.iter();
    while let Some(flag) = it.next() {
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        let num = || {
            value
                .parse::<u64>()
                .map_err(|_| format!("{flag} {value}: not a number"))
        };
        match flag.as_str() {
            "--port" => port = num()? as u16,
            "--matching" => rule = rule.matching(value),
            "--after" => rule = rule.after(num()?),
            "--times" => rule = rule.times(num()?),
            "--stats" => stats = Some(std::path::PathBuf::from(value)),
            _ => return Err(usage.into()),
        }
    }
    let p = Proxy::start_on(std::net::SocketAddr::from(([127, 0, 0, 1], upstream)), port);
    p.set(vec![rule]);
    println!("{}", p.port());
    let _ = std::io::stdout().flush();
    let mut last = u64::MAX;
    loop {
        std::thread::sleep(std::time::Duration::from_millis(20));
        let n = p.log().len() as u64;
        if let Some(path) = &stats
            && n != last
        {
            last = n;
            let tmp = path.with_extension("tmp");
            let text = format!(
                "requests={} faults={} bytes={}\n",
                p.requests(),
                p.faults(),
                p.bytes()
            );
            std::fs::write(&tmp, text)
                .and_then(|()| std::fs::rename(&tmp, path))
                .map_err(|e| format!("{}: {e}", path.display()))?;
        }
    }
}
