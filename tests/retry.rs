//! The inspector never freezes on a bad network (issue 39): a dataset served by
//! `python3 -m http.server` whose server is stopped while tiles are still to
//! load, then started again on the same port. Tiles that fail are retried in
//! the background with a growing wait (never in a tight loop), the tiles loaded
//! before are still drawn, and once the server is back the tiles load by
//! themselves: in the tile cache with nobody asking again, in the inspector's
//! render worker as a new frame with no new request, and in the real inspector
//! in tmux, whose status line says "retrying N requests" and then what failed,
//! and recovers without a key press. Every wait polls for readiness. With
//! CI=true a missing python3 or tmux is a failure, else a skip.

mod common;

use common::http::{HttpServer, scan_dataset};
use pcimg::camera::Camera;
use pcimg::lod::cache::retry_wait;
use pcimg::lod::{self, LodMode, TileCache, TileRef};
use pcimg::store::Dataset;
use pcimg::tui::app::{LodChoice, Settings};
use pcimg::tui::worker::{FrameReady, RenderWorker, Report, Request};
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Points of the synthetic scan: several parts under the 1 MiB budget.
const POINTS: u64 = 200_000;

/// The most tries a tile can have had `elapsed` after its first failure: the
/// k-th comes at least half of each wait before it later (the jitter keeps
/// 50-100 % of a wait), however slow the machine.
fn most_attempts(elapsed: Duration) -> u32 {
    let mut k = 1;
    let mut earliest = Duration::ZERO;
    loop {
        earliest += retry_wait(k) / 2;
        if earliest > elapsed {
            return k;
        }
        k += 1;
    }
}

/// The overview's top tiles (loaded first by the inspector), as a selection.
fn overview_top(ds: &Dataset) -> Vec<TileRef> {
    ds.overview_first(1_000_000)
        .into_iter()
        .map(|(part, level, tile, points)| TileRef {
            part,
            level,
            tile,
            points,
            bounds: ds.bounds(),
        })
        .collect()
}

/// The finest tiles of the whole view that lie in parts not opened yet (their
/// first read opens the part: a request to the server).
fn unopened_finest(ds: &Dataset) -> Vec<TileRef> {
    let cam = Camera::fit(&ds.bounds());
    lod::select(ds, &cam, 800, 600, LodMode::Fixed(0), u64::MAX)
        .tiles
        .into_iter()
        .filter(|t| ds.part(t.part).is_some_and(|p| !p.is_open()))
        .collect()
}

#[test]
fn failed_tiles_are_retried_in_the_background_until_the_server_returns() {
    let dir = tempfile::tempdir().unwrap();
    scan_dataset(dir.path(), "scan.pcimg", POINTS);
    let Some(mut server) = HttpServer::start(dir.path()) else {
        return;
    };
    let url = server.url("scan.pcimg");
    let ds = Arc::new(Dataset::open(Path::new(&url)).unwrap());
    let cache = TileCache::new(ds.clone(), 1 << 30, 4);
    let top = overview_top(&ds);
    assert!(!top.is_empty(), "the dataset has an overview");
    cache.load_all(&top).unwrap();
    let fine = unopened_finest(&ds);
    assert!(fine.len() >= 2, "{} tiles in unopened parts", fine.len());

    server.stop();
    cache.request(&fine);
    // Every tile fails once (the server refuses), and waits to be tried again.
    let deadline = Instant::now() + Duration::from_secs(120);
    while cache.retries().tiles < fine.len() {
        assert!(Instant::now() < deadline, "{}", cache.retries());
        let _ = cache.arrivals.recv_timeout(Duration::from_millis(100));
    }
    let r = cache.retries();
    assert_eq!(r.tiles, fine.len(), "{r}");
    assert_eq!(cache.retrying(&fine), fine.len());
    assert_eq!(
        cache.unreadable(&fine),
        0,
        "a refused request is not bad data"
    );
    assert!(
        cache.take_errors().is_empty(),
        "retried failures are not errors"
    );
    let e = r.last_error.as_ref().expect("the latest failure");
    assert!(e.transient(), "{e}");
    let text = r.to_string();
    assert!(
        text.contains(&format!("{} tiles waiting to retry", fine.len()))
            && text.contains(&format!("127.0.0.1:{}", server.port))
            && text.contains("scan.pcimg"),
        "{text}"
    );
    assert!(r.next_in.is_some(), "{text}");
    // The tiles loaded before are still there, and stand in for the missing.
    assert_eq!(cache.ready(&top).len(), top.len());
    assert!(!cache.stand_ins(&fine).is_empty());
    assert!(cache.ready(&fine).is_empty());

    // Tried again by the cache itself (nobody asks), with a growing wait.
    let deadline = Instant::now() + Duration::from_secs(60);
    let r = loop {
        let r = cache.retries();
        assert!(
            r.attempts <= most_attempts(r.failing_for),
            "{} tries in {:?}: a tight loop",
            r.attempts,
            r.failing_for
        );
        if r.attempts >= 3 {
            break r;
        }
        assert!(Instant::now() < deadline, "not tried again: {r}");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(r.tiles, fine.len(), "{r}");

    // The server returns on the same port: the tiles load with no new request.
    server.restart();
    let back = Instant::now();
    let deadline = back + Duration::from_secs(60);
    while !cache.has_all(&fine) {
        assert!(
            Instant::now() < deadline,
            "not recovered 60 s after the server returned: {}",
            cache.retries()
        );
        let _ = cache.arrivals.recv_timeout(Duration::from_millis(100));
    }
    eprintln!("recovered {:?} after the server returned", back.elapsed());
    assert_eq!(cache.retries().tiles, 0);
    assert_eq!(cache.retrying(&fine), 0);
    assert!(cache.take_errors().is_empty());
}

/// The next frame report, at most 60 s away.
fn next_frame(w: &RenderWorker, what: &str, done: impl Fn(&FrameReady) -> bool) -> Box<FrameReady> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "no frame in 60 s with {what}");
        match w.recv_timeout(Duration::from_millis(200)) {
            Some(Report::Frame(f)) if done(&f) => return f,
            Some(Report::Error(e)) => panic!("worker error: {e}"),
            _ => {}
        }
    }
}

#[test]
fn the_render_worker_redraws_by_itself_when_the_server_returns() {
    let dir = tempfile::tempdir().unwrap();
    scan_dataset(dir.path(), "scan.pcimg", POINTS);
    let Some(mut server) = HttpServer::start(dir.path()) else {
        return;
    };
    let url = server.url("scan.pcimg");
    let ds = Arc::new(Dataset::open(Path::new(&url)).unwrap());
    let w = common::halfblock_worker(ds.clone());
    let mut settings = Settings {
        budget: 1_000,
        ..Default::default()
    };
    let request = |seq: u64, settings: &Settings| Request {
        seq,
        camera: Camera::fit(&ds.bounds()),
        settings: settings.clone(),
        cursor: None,
        pick: false,
        cells: (80, 30),
        cell_pixels: (1, 2),
        scale: 1,
        allowance: None,
        pixel_marks: None,
    };
    // A first frame of the overview, whole.
    w.request(request(1, &settings));
    next_frame(&w, "the overview", |f| f.status.pending == 0);
    let fine = unopened_finest(&ds);
    assert!(fine.len() >= 2, "{} tiles in unopened parts", fine.len());

    server.stop();
    settings.lod = LodChoice::Pinned(0);
    w.request(request(2, &settings));
    // Nothing is loading any more, the missing tiles wait for a retry, and
    // the frame still draws what it has.
    let f = next_frame(&w, "every failed tile waiting", |f| {
        f.seq == 2
            && f.status.pending == 0
            && f.status
                .retry
                .as_ref()
                .is_some_and(|r| r.tiles >= fine.len())
    });
    assert!(f.status.points > 0, "the tiles loaded before are drawn");
    let r = f.status.retry.as_ref().unwrap();
    assert!(
        r.error.contains(&format!("127.0.0.1:{}", server.port)),
        "{}",
        r.error
    );
    assert!(
        r.describe()
            .starts_with(&format!("retrying {} requests", r.tiles)),
        "{}",
        r.describe()
    );

    // Back: a frame with every tile of level 0, and no request sent since.
    server.restart();
    let back = Instant::now();
    let f = next_frame(&w, "every tile loaded", |f| {
        f.status.retry.is_none() && f.status.pending == 0
    });
    eprintln!("frame {:?} after the server returned", back.elapsed());
    assert_eq!(f.seq, 2, "the frame answers the request made before");
    assert_eq!(f.status.levels, Some((0, 0)));
    assert_eq!(f.status.unreadable, 0);
}

#[test]
fn the_inspector_says_retrying_and_recovers_without_a_key_in_tmux() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    scan_dataset(dir.path(), "scan.pcimg", POINTS);
    let Some(mut server) = HttpServer::start(dir.path()) else {
        return;
    };
    let url = server.url("scan.pcimg");
    let tmux = common::tmux::Tmux::new("retry");
    tmux.inspect((160, 45), Path::new(&url), "--budget 1000");
    tmux.wait_for("the first frame", 60, |s| {
        s.contains("overview") && !s.contains("loading") && !s.contains("no frame yet")
    });
    server.stop();
    // Level 0: tiles of parts never opened, which the stopped server refuses.
    tmux.run(&["send-keys", "-t", "t", "0"]);
    let s = tmux.wait_for("the status line to say retrying", 60, |s| {
        s.contains("retrying") && s.contains("pinned level 0")
    });
    // What was loaded before is still drawn (the overview standing in).
    assert!(s.contains(" pts / ") && !s.contains("| 0 pts /"), "{s}");
    // Then what failed: the server's address and what to do.
    tmux.wait_for("the status line to say what failed", 60, |s| {
        s.contains("retrying") && s.contains("nothing answers at 127.0.0.1")
    });
    server.restart();
    // No key is pressed: the inspector recovers by itself.
    let s = tmux.wait_for("the inspector to recover", 60, |s| {
        !s.contains("retrying")
            && !s.contains("loading")
            && s.contains("pinned level 0 | level 0 |")
    });
    assert!(!s.contains("unreadable"), "{s}");
    tmux.run(&["send-keys", "-t", "t", "q"]);
}
