//! The inspector after an outage (issue 39): how long from the server's return
//! to the frame with every tile. A dataset's folder served by
//! `python3 -m http.server` on 127.0.0.1; the inspector's render worker (CPU
//! rasterizer, half-blocks, 2 loading threads as `inspect` has by default)
//! draws the overview; the server is stopped and level 0 asked for (its parts
//! were never opened, so every tile fails); after OUTAGE seconds the server is
//! started again on the same port, and the clock runs from the moment its port
//! accepts connections to the worker's first frame with nothing loading and
//! nothing waiting to be retried (no request is sent meanwhile: the worker
//! redraws by itself). Also the requests that failed during the outage (the
//! retries' cost to a server that is down).
//!
//! ```sh
//! cargo run --release --example retry_recovery -- DIR NAME [REPS] [OUTAGE_S,...]
//! ```
//!
//! DIR is served; NAME is the dataset's folder in it (`bench/retry.sh` makes
//! one). Each run opens the dataset anew (nothing cached from the run before).

use pcimg::camera::Camera;
use pcimg::render::RendererChoice;
use pcimg::store::Dataset;
use pcimg::tui::app::{LodChoice, Settings};
use pcimg::tui::protocol::{Encoding, Graphics};
use pcimg::tui::worker::{FrameReady, RenderWorker, Report, Request, WorkerOptions};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

struct Server {
    dir: PathBuf,
    port: u16,
    child: Option<Child>,
}

impl Server {
    fn start(&mut self) -> anyhow::Result<Instant> {
        let child = Command::new("python3")
            .args(["-m", "http.server", "--bind", "127.0.0.1"])
            .arg(self.port.to_string())
            .arg("--directory")
            .arg(&self.dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        self.child = Some(child);
        let addr = std::net::SocketAddr::from(([127, 0, 0, 1], self.port));
        let t = Instant::now();
        loop {
            if std::net::TcpStream::connect_timeout(&addr, Duration::from_millis(100)).is_ok() {
                return Ok(Instant::now());
            }
            anyhow::ensure!(
                t.elapsed() < Duration::from_secs(30),
                "python3 -m http.server did not listen in 30 s"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
    }
}

fn frame(
    w: &RenderWorker,
    what: &str,
    done: impl Fn(&FrameReady) -> bool,
) -> anyhow::Result<Box<FrameReady>> {
    let deadline = Instant::now() + Duration::from_secs(180);
    loop {
        anyhow::ensure!(Instant::now() < deadline, "no frame with {what} in 180 s");
        match w.recv_timeout(Duration::from_millis(100)) {
            Some(Report::Frame(f)) if done(&f) => return Ok(f),
            Some(Report::Error(e)) => anyhow::bail!("worker error: {e}"),
            _ => {}
        }
    }
}

struct Run {
    recovered_ms: f64,
    tiles: usize,
    failed_requests: u64,
}

fn one(server: &mut Server, url: &str, outage: Duration) -> anyhow::Result<Run> {
    server.start()?;
    pcimg::remote::file::forget_cached(url);
    let ds = Arc::new(Dataset::open(Path::new(url))?);
    let w = RenderWorker::spawn(
        ds.clone(),
        WorkerOptions {
            encoding: Encoding::new(Graphics::Halfblocks),
            extra_bands: Vec::new(),
            renderer: RendererChoice::Cpu,
            memory: 2 << 30,
            load_threads: 2,
        },
    );
    let mut settings = Settings {
        budget: 1_000,
        ..Default::default()
    };
    let request = |seq, settings: &Settings| Request {
        seq,
        camera: Camera::fit(&ds.bounds()),
        settings: settings.clone(),
        cursor: None,
        pick: false,
        cells: (120, 40),
        cell_pixels: (1, 2),
        scale: 1,
        allowance: None,
        pixel_marks: None,
    };
    w.request(request(1, &settings));
    frame(&w, "the overview", |f| f.status.pending == 0)?;
    server.stop();
    let stopped = Instant::now();
    let failed = pcimg::remote::stats().failed;
    settings.lod = LodChoice::Pinned(0);
    w.request(request(2, &settings));
    let f = frame(&w, "every tile waiting for a retry", |f| {
        f.seq == 2 && f.status.pending == 0 && f.status.retry.is_some()
    })?;
    let tiles = f.status.retry.as_ref().map_or(0, |r| r.tiles);
    std::thread::sleep(outage.saturating_sub(stopped.elapsed()));
    let failed_requests = pcimg::remote::stats().failed - failed;
    let back = server.start()?;
    let f = frame(&w, "every tile", |f| {
        f.status.retry.is_none() && f.status.pending == 0
    })?;
    anyhow::ensure!(f.status.levels == Some((0, 0)), "{:?}", f.status.levels);
    let recovered_ms = back.elapsed().as_secs_f64() * 1e3;
    server.stop();
    Ok(Run {
        recovered_ms,
        tiles,
        failed_requests,
    })
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(dir), Some(name)) = (args.first(), args.get(1)) else {
        anyhow::bail!("usage: retry_recovery DIR NAME [REPS] [OUTAGE_S,...]");
    };
    let reps: usize = args.get(2).map_or(Ok(5), |a| a.parse())?;
    let outages: Vec<f64> = args
        .get(3)
        .map_or("3,30", |s| s.as_str())
        .split(',')
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let mut server = Server {
        dir: PathBuf::from(dir),
        port,
        child: None,
    };
    let url = format!("http://127.0.0.1:{port}/{name}");
    for outage in outages {
        let mut ms = Vec::new();
        let mut failed = Vec::new();
        let mut tiles = 0;
        for _ in 0..reps {
            let r = one(&mut server, &url, Duration::from_secs_f64(outage))?;
            ms.push(r.recovered_ms);
            failed.push(r.failed_requests as f64);
            tiles = r.tiles;
        }
        let (lo, hi) = (
            ms.iter().copied().fold(f64::INFINITY, f64::min),
            ms.iter().copied().fold(0.0, f64::max),
        );
        println!(
            "outage {outage} s, {tiles} tiles waiting: server back -> full frame median {:.0} ms \
             ({lo:.0}-{hi:.0}), {reps} runs; requests failed during the outage: median {:.0}",
            median(&mut ms),
            median(&mut failed)
        );
    }
    Ok(())
}
