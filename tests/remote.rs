//! Datasets in object storage (issue 30), over object_store's in-memory store
//! with added latency: a dataset of 144 parts opens with one request (its index);
//! a part is fetched from only when its tiles are read; the first frame's tiles
//! need a few dozen requests; what comes back equals the local dataset's points.

mod common;
use object_store::memory::InMemory;
use object_store::throttle::{ThrottleConfig, ThrottledStore};
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};
use pcimg::remote::Remote;
use pcimg::store::Dataset;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// The parts of `ds` whose files have been read.
fn opened(ds: &Dataset) -> usize {
    ds.parts().unwrap().iter().filter(|p| p.is_open()).count()
}

/// `nx` × `ny` parts of a terrain, each its own file, indexed.
fn dataset(dir: &Path, nx: usize, ny: usize, per_part: usize) -> std::path::PathBuf {
    common::grid_dataset(dir, nx, ny, per_part)
}

/// Every file under `dir` put into an in-memory store under `prefix`, behind
/// `latency` per request.
fn upload(dir: &Path, prefix: &str, latency: Duration) -> Arc<dyn ObjectStore> {
    let mem = InMemory::new();
    let mut stack = vec![dir.to_path_buf()];
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            let rel = p
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            let loc = object_store::path::Path::from(format!("{prefix}/{rel}"));
            let bytes = std::fs::read(&p).unwrap();
            rt.block_on(mem.put(&loc, PutPayload::from(bytes))).unwrap();
        }
    }
    let cfg = ThrottleConfig {
        wait_get_per_call: latency,
        ..Default::default()
    };
    Arc::new(ThrottledStore::new(mem, cfg))
}

#[test]
fn a_remote_dataset_opens_with_one_request_and_reads_parts_only_when_needed() {
    let dir = tempfile::tempdir().unwrap();
    let local = dataset(dir.path(), 12, 12, 300);
    let store = upload(&local, "city.pcimg", Duration::from_millis(5));
    let remote = Arc::new(Remote::with_store(
        store,
        "city.pcimg",
        "memory://city.pcimg",
    ));
    let ds = Dataset::open_remote(remote.clone()).unwrap();
    let count = || remote.requests.load(Ordering::Relaxed);
    assert_eq!(count(), 1, "opening is one request for the index");
    assert_eq!(ds.part_count(), 144);
    assert!(ds.parts().unwrap().into_iter().all(|p| !p.is_open()));
    let here = Dataset::open(&local).unwrap();
    assert_eq!(ds.points(), here.points());

    // One part's level 0: its head, then its tiles (merged into few requests).
    let bands: Vec<usize> = (0..4).collect();
    let a = ds.parts().unwrap()[17].read_level(0, &bands).unwrap();
    let b = here.parts().unwrap()[17].read_level(0, &bands).unwrap();
    assert_eq!(a.columns, b.columns);
    let after_one = count();
    // These parts' index entries record no head length (`head` 0, as parts
    // written before head-first layout): the head is walked by successive ranges
    // (header and first 64 KiB, then directories and their values), then tiles.
    assert!(
        (3..=8).contains(&after_one),
        "the index, the part's head (with its ETag) and its tiles: {after_one} requests"
    );
    assert_eq!(opened(&ds), 1);
    // Read again: from the memory cache.
    let _ = ds.parts().unwrap()[17].read_level(0, &bands).unwrap();
    assert_eq!(count(), after_one);

    // The first frame of the whole dataset: the overview's top tiles.
    let first = ds.overview_first(1 << 40);
    assert!(!first.is_empty());
    let before = count();
    for &(part, level, tile, _) in &first {
        let p = ds.part(part).unwrap();
        let got = p.read_tiles(level, &[tile], &bands).unwrap();
        let want = here
            .part(part)
            .unwrap()
            .read_tiles(level, &[tile], &bands)
            .unwrap();
        assert_eq!(got.columns, want.columns);
    }
    let frame = count() - before;
    let nodes = ds.node_count() as u64;
    assert!(
        frame <= 48,
        "first frame took {frame} requests for {nodes} overview nodes"
    );
    // No part below the overview was touched.
    assert_eq!(opened(&ds), 1);
}

#[test]
fn a_remote_part_of_an_older_layout_opens_by_successive_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let local = dataset(dir.path(), 1, 1, 5000);
    let store = upload(&local, "one", Duration::ZERO);
    let remote = Arc::new(Remote::with_store(
        store,
        "one/tile-00-00.tif",
        "memory://one/tile-00-00.tif",
    ));
    let ds = Dataset::open_remote(remote.clone()).unwrap();
    let here = Dataset::open(&local.join("tile-00-00.tif")).unwrap();
    let bands: Vec<usize> = (0..4).collect();
    for l in 0..here.parts().unwrap()[0].levels.len() {
        assert_eq!(
            ds.parts().unwrap()[0]
                .read_level(l, &bands)
                .unwrap()
                .columns,
            here.parts().unwrap()[0]
                .read_level(l, &bands)
                .unwrap()
                .columns
        );
    }
}

#[test]
fn remote_errors_name_the_url_and_what_to_fix() {
    let dir = tempfile::tempdir().unwrap();
    let local = dataset(dir.path(), 1, 1, 100);
    let store = upload(&local, "here", Duration::ZERO);
    let remote = Arc::new(Remote::with_store(
        store.clone(),
        "elsewhere",
        "memory://b/elsewhere",
    ));
    let e = Dataset::open_remote(remote).unwrap_err();
    // The facts, typed (what to do is the command line's to say).
    let failed = *e.remote.clone().expect("a failed request");
    assert_eq!(failed.url, "memory://b/elsewhere/pcimg-index.json");
    assert_eq!(failed.problem, pcimg::remote::Problem::NotFound);
    let e = e.to_string();
    assert!(e.contains("memory://b/elsewhere/pcimg-index.json"), "{e}");
    assert!(
        e.contains("not found") && e.contains("dataset index"),
        "{e}"
    );
    let remote = Arc::new(Remote::with_store(
        store,
        "here/nothing.tif",
        "memory://b/here/nothing.tif",
    ));
    let e = Dataset::open_remote(remote).unwrap_err().to_string();
    assert!(
        e.contains("memory://b/here/nothing.tif") && e.contains("404"),
        "{e}"
    );
}

/// A file of `n` pseudo-random bytes.
fn noise(path: &Path, n: usize, seed: u64) -> Vec<u8> {
    let mut r = pcimg::synth::Rng::new(seed);
    let v: Vec<u8> = (0..n).map(|_| (r.f64() * 256.0) as u8).collect();
    std::fs::write(path, &v).unwrap();
    v
}

#[test]
fn uploads_arrive_whole_and_an_interrupted_one_leaves_nothing() {
    use pcimg::remote::upload::{MULTIPART_ABOVE, Uploader};
    use std::sync::atomic::AtomicBool;
    let dir = tempfile::tempdir().unwrap();
    let small = dir.path().join("small.bin");
    let big = dir.path().join("big.bin");
    let small_bytes = noise(&small, 1000, 1);
    // Above the multipart threshold, and not a whole number of parts.
    let big_bytes = noise(&big, MULTIPART_ABOVE as usize + 4321, 2);
    let mem = Arc::new(InMemory::new());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let listed = |prefix: &str| -> Vec<String> {
        use futures_util::TryStreamExt;
        let p = object_store::path::Path::from(prefix);
        let v: Vec<object_store::ObjectMeta> =
            rt.block_on(mem.list(Some(&p)).try_collect()).unwrap();
        v.into_iter().map(|m| m.location.to_string()).collect()
    };
    let remote = Arc::new(Remote::with_store(mem.clone(), "up", "memory://b/up"));
    let up = Uploader::new(remote.clone(), Arc::new(AtomicBool::new(false)));
    up.start(&small, "a/small.bin").unwrap();
    up.start(&big, "big.bin").unwrap();
    up.wait().unwrap();
    assert_eq!(up.sent(), (small_bytes.len() + big_bytes.len()) as u64);
    let get = |name: &str| {
        let loc = object_store::path::Path::from(name);
        rt.block_on(async { mem.get(&loc).await.unwrap().bytes().await.unwrap() })
    };
    assert_eq!(get("up/a/small.bin").as_ref(), &small_bytes[..]);
    assert_eq!(get("up/big.bin").as_ref(), &big_bytes[..]);
    // Removing what was uploaded.
    assert!(up.remove_all().is_empty());
    assert!(listed("up").is_empty());

    // Interrupted in the middle of a slow multipart upload (each part takes
    // 400 ms): aborted, nothing visible, the error says so.
    let slow: Arc<dyn ObjectStore> = Arc::new(ThrottledStore::new(
        InMemory::new(),
        ThrottleConfig {
            wait_put_per_call: Duration::from_millis(400),
            ..Default::default()
        },
    ));
    let remote = Arc::new(Remote::with_store(slow.clone(), "up", "memory://b/up"));
    let cancel = Arc::new(AtomicBool::new(false));
    let up = Uploader::new(remote, cancel.clone());
    let t = std::time::Instant::now();
    up.start(&big, "big.bin").unwrap();
    std::thread::sleep(Duration::from_millis(150));
    cancel.store(true, Ordering::Relaxed);
    let e = up.wait().unwrap_err();
    assert!(
        e.contains("memory://b/up/big.bin") && e.contains("interrupted"),
        "{e}"
    );
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    let v: Vec<object_store::ObjectMeta> = rt
        .block_on(futures_util::TryStreamExt::try_collect(slow.list(None)))
        .unwrap();
    assert!(v.is_empty(), "{v:?}");
}

#[test]
fn a_queued_upload_survives_its_directory_being_moved() {
    // The conversion publishes (renames) its staging directory while uploads of
    // its last parts still wait their turn: each file is opened when queued.
    use pcimg::remote::upload::Uploader;
    use std::sync::atomic::AtomicBool;
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage");
    std::fs::create_dir(&stage).unwrap();
    let slow: Arc<dyn ObjectStore> = Arc::new(ThrottledStore::new(
        InMemory::new(),
        ThrottleConfig {
            wait_put_per_call: Duration::from_millis(150),
            ..Default::default()
        },
    ));
    let remote = Arc::new(Remote::with_store(slow.clone(), "ds", "memory://b/ds"));
    let up = Uploader::new(remote, Arc::new(AtomicBool::new(false)));
    let mut want = Vec::new();
    for i in 0..8 {
        let p = stage.join(format!("part-{i:05}.tif"));
        want.push(noise(&p, 5000 + i, i as u64));
        up.start(&p, &format!("part-{i:05}.tif")).unwrap();
    }
    std::fs::rename(&stage, dir.path().join("published")).unwrap();
    up.wait().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    for (i, w) in want.iter().enumerate() {
        let loc = object_store::path::Path::from(format!("ds/part-{i:05}.tif"));
        let got = rt.block_on(async { slow.get(&loc).await.unwrap().bytes().await.unwrap() });
        assert_eq!(got.as_ref(), &w[..]);
    }
}

/// Every level of every band of `ds`'s parts `which`, read.
fn read_all(ds: &Dataset, which: &[usize]) -> Vec<Vec<Vec<f32>>> {
    let mut out = Vec::new();
    for &i in which {
        let p = &ds.parts().unwrap()[i];
        let bands: Vec<usize> = (0..p.bands.len()).collect();
        for l in 0..p.levels.len() {
            out.push(p.read_level(l, &bands).unwrap().columns);
        }
    }
    out
}

#[test]
fn a_converted_dataset_reads_warm_without_heads_and_a_replaced_part_is_an_error() {
    use pcimg::convert::{Quiet, upload::RemoteOutput};
    use pcimg::store::dataset::index::{INDEX_FILE, Index};
    use std::sync::atomic::AtomicBool;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.xyz");
    pcimg::synth::write_text(&input, 450_000, 7).unwrap();
    // `convert -o URL` into an in-memory store (the ETags its uploads return).
    let mem = Arc::new(InMemory::new());
    let url = "memory://b/etag.pcimg";
    let remote = |url: &str| Arc::new(Remote::with_store(mem.clone(), "etag.pcimg", url));
    let cancel = Arc::new(AtomicBool::new(false));
    let out = RemoteOutput::prepare_in(remote(url), false, cancel.clone()).unwrap();
    let mut o = common::convert_options(out.local.clone(), 1 << 20);
    o.on_part = Some(out.hook());
    o.cancel = cancel;
    pcimg::convert::convert(&input, &o, &Quiet).unwrap();
    out.finish(&Quiet).unwrap();
    drop(out);
    let (text, _, _) = remote(url).get(INDEX_FILE).unwrap().unwrap();
    let root = Index::parse(&text, Path::new(url)).unwrap();
    assert_eq!(root.uploaded_to(), Some(url));
    let page = |n: &str| Ok(remote(url).get(n).unwrap().unwrap().0.to_vec());
    let index = root.listing(Path::new(url), &page).unwrap();
    assert!(index.parts.len() >= 3, "{} parts", index.parts.len());
    assert!(index.parts.iter().all(|p| p.etag.is_some()));
    assert!(index.nodes.iter().all(|n| n.etag.is_some()));

    let cache = dir.path().join("cache");
    pcimg::remote::disk::configure(&cache, 64 << 20).unwrap();
    let every: Vec<usize> = (0..index.parts.len()).collect();
    // Cold: the index, then each part's head and tiles; no HEAD is needed,
    // so every request but the index's is a ranged GET of data.
    let r1 = remote(url);
    let ds = Dataset::open_remote(r1.clone()).unwrap();
    let cold = read_all(&ds, &every);
    let cold_requests = r1.requests.load(Ordering::Relaxed);
    assert!(cold_requests > 1 + every.len() as u64, "{cold_requests}");
    // Warm, as a new process (the memory cache forgotten): the index only.
    pcimg::remote::file::forget_cached(url);
    let (hits0, _, _) = pcimg::remote::disk::counters();
    let r2 = remote(url);
    let ds = Dataset::open_remote(r2.clone()).unwrap();
    assert_eq!(read_all(&ds, &every), cold);
    assert_eq!(
        r2.requests.load(Ordering::Relaxed),
        1,
        "a warm open and read of every part is the index request alone (no HEAD)"
    );
    assert!(pcimg::remote::disk::counters().0 > hits0);

    // A part replaced behind the index (other bytes, so another ETag): what
    // the cache does not hold is refused, never mixed with the indexed data.
    let victim = &index.parts[1].file;
    let other = &index.parts[2].file;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let loc = |n: &str| object_store::path::Path::from(format!("etag.pcimg/{n}"));
    let bytes = rt
        .block_on(async { mem.get(&loc(other)).await.unwrap().bytes().await })
        .unwrap();
    rt.block_on(mem.put(&loc(victim), PutPayload::from(bytes)))
        .unwrap();
    pcimg::remote::file::forget_cached(url);
    pcimg::remote::disk::disable();
    let ds = Dataset::open_remote(remote(url)).unwrap();
    let p = &ds.parts().unwrap()[1];
    let e = p.read_level(0, &[0, 1, 2]).unwrap_err().to_string();
    assert!(
        e.contains(&format!("{url}/{victim}")) && e.contains("changed since the index was written"),
        "{e}"
    );
    // The parts not replaced still read as before.
    let first = ds.parts().unwrap()[0].levels.len();
    assert_eq!(read_all(&ds, &[0]), cold[..first].to_vec());

    // The same index read from another URL (a copy made by other tools): the
    // recorded ETags are not trusted there; it reads as an index without them.
    let copy = "memory://b/copy.pcimg";
    let r3 = Arc::new(Remote::with_store(mem.clone(), "etag.pcimg", copy));
    let ds = Dataset::open_remote(r3).unwrap();
    assert_eq!(read_all(&ds, &[0]), cold[..first].to_vec());
}

/// This process's open files whose path contains `marker`.
fn open_files_named(marker: &str) -> usize {
    std::fs::read_dir("/proc/self/fd")
        .map(|d| {
            d.filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
                .filter(|p| p.to_string_lossy().contains(marker))
                .count()
        })
        .unwrap_or(0)
}

#[test]
fn queued_uploads_hold_no_open_file_each() {
    // Thousands of parts queued at once must stay within the open-file limit:
    // a queued file is held by a hard link and opened when its upload starts.
    use pcimg::remote::upload::Uploader;
    use std::sync::atomic::AtomicBool;
    if !Path::new("/proc/self/fd").is_dir() {
        eprintln!("note: no /proc/self/fd, skipping");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let slow: Arc<dyn ObjectStore> = Arc::new(ThrottledStore::new(
        InMemory::new(),
        ThrottleConfig {
            wait_put_per_call: Duration::from_millis(20),
            ..Default::default()
        },
    ));
    let remote = Arc::new(Remote::with_store(slow.clone(), "ds", "memory://b/fds"));
    let up = Uploader::new(remote, Arc::new(AtomicBool::new(false)));
    let n = 300;
    let mut want = Vec::new();
    for i in 0..n {
        let p = dir.path().join(format!("fdtest-part-{i:05}.tif"));
        want.push(noise(&p, 100 + i, i as u64));
        up.start(&p, &format!("part-{i:05}.tif")).unwrap();
    }
    // The sources are gone before most uploads start: the links keep them.
    for i in 0..n {
        std::fs::remove_file(dir.path().join(format!("fdtest-part-{i:05}.tif"))).unwrap();
    }
    let queued = open_files_named("fdtest-part-");
    assert!(up.pending() > n / 2, "{} pending", up.pending());
    assert!(queued <= 8, "{queued} files open with {n} uploads queued");
    up.wait().unwrap();
    assert_eq!(open_files_named("fdtest-part-"), 0);
    let q = up.queue_dir().unwrap();
    assert_eq!(std::fs::read_dir(q).unwrap().count(), 0, "links removed");
    for (i, w) in want.iter().enumerate() {
        assert_eq!(
            up.uploaded(&format!("part-{i:05}.tif")).unwrap().0,
            w.len() as u64
        );
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    for i in [0, n / 2, n - 1] {
        let loc = object_store::path::Path::from(format!("ds/part-{i:05}.tif"));
        let got = rt.block_on(async { slow.get(&loc).await.unwrap().bytes().await.unwrap() });
        assert_eq!(got.as_ref(), &want[i][..]);
    }
    let q = q.to_path_buf();
    drop(up);
    assert!(!q.exists(), "the queue folder is removed");
}

/// The first frame of a whole dataset as a viewer draws it: the tiles selected
/// for a top view under a point budget, read.
fn first_frame(ds: &Dataset, budget: u64) -> u64 {
    use pcimg::camera::Camera;
    use pcimg::lod::{self, LodMode};
    let cam = Camera::fit(&ds.bounds());
    let sel = lod::select(ds, &cam, 320, 200, LodMode::View { budget }, 1 << 30);
    assert_eq!(sel.dropped_tiles, 0);
    let mut points = 0;
    for t in &sel.tiles {
        let p = ds.part(t.part).unwrap();
        let bands: Vec<usize> = (0..p.bands.len()).collect();
        points += p.read_tiles(t.level, &[t.tile], &bands).unwrap().len() as u64;
    }
    points
}

#[test]
fn a_paged_index_opens_in_one_request_and_its_first_frame_costs_what_a_small_one_does() {
    // 400 and 10,000 parts (issue 44, test-sized): opening is one request of
    // at most 256 KB whatever the parts; the first frame fetches the pages
    // the view reaches, and reads about as many bytes at both sizes.
    let dir = tempfile::tempdir().unwrap();
    let mut seen = Vec::new();
    for side in [20, 100] {
        let local = dataset(dir.path(), side, side, 20);
        let store = upload(&local, "n.pcimg", Duration::ZERO);
        let remote = Arc::new(Remote::with_store(store, "n.pcimg", "memory://n.pcimg"));
        let ds = Dataset::open_remote(remote.clone()).unwrap();
        let (requests, bytes) = (
            remote.requests.load(Ordering::Relaxed),
            remote.received.load(Ordering::Relaxed),
        );
        assert_eq!(requests, 1, "{side}²: opening is one request");
        assert!(bytes <= 256 << 10, "{side}²: opening read {bytes} bytes");
        assert_eq!(ds.part_count(), side * side);
        let (pages, loaded) = ds.index_pages();
        assert_eq!(loaded, 1);
        // (A budget well under the smaller dataset's 8,000 points: a frame
        // of a dataset far larger than the view.)
        let points = first_frame(&ds, 2_000);
        assert!(points > 0);
        let frame_requests = remote.requests.load(Ordering::Relaxed) - requests;
        let frame_bytes = remote.received.load(Ordering::Relaxed) - bytes;
        let (fetched, _) = ds.pages_fetched();
        // The same frame from the local dataset: the same points.
        let here = Dataset::open(&local).unwrap();
        assert_eq!(first_frame(&here, 2_000), points);
        seen.push((
            side * side,
            pages,
            fetched,
            frame_requests,
            bytes + frame_bytes,
        ));
    }
    // (parts, pages, pages fetched, first-frame requests, bytes before it)
    eprintln!("{seen:?}");
    let (small, large) = (seen[0], seen[1]);
    assert!(large.1 > 1, "10,000 parts: a paged index ({seen:?})");
    assert!(
        large.2 < large.1 as u64 / 4,
        "the first frame reads a few of the pages: {seen:?}"
    );
    assert!(large.3 <= 48, "a few dozen requests: {seen:?}");
    assert!(
        large.4 <= 2 * small.4,
        "bytes before the first frame hardly grow with the parts: {seen:?}"
    );
}

#[test]
fn a_paged_dataset_uploads_its_pages_last_with_etags_and_a_forced_replace_removes_them() {
    use pcimg::convert::{Quiet, upload::RemoteOutput};
    use pcimg::store::dataset::index::{INDEX_FILE, Index};
    use std::sync::atomic::AtomicBool;
    let dir = tempfile::tempdir().unwrap();
    let mem = Arc::new(InMemory::new());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let listed = || -> Vec<String> {
        use futures_util::TryStreamExt;
        let p = object_store::path::Path::from("paged.pcimg");
        let v: Vec<object_store::ObjectMeta> =
            rt.block_on(mem.list(Some(&p)).try_collect()).unwrap();
        let mut v: Vec<String> = v.into_iter().map(|m| m.location.to_string()).collect();
        v.sort();
        v
    };
    let url = "memory://b/paged.pcimg";
    let remote = |u: &str| Arc::new(Remote::with_store(mem.clone(), "paged.pcimg", u));
    // What `convert -o URL` does once its parts are written: upload them, then
    // the index (a paged one: 400 parts) with every object's ETag.
    let upload = |grid: &Path, force: bool| {
        let cancel = Arc::new(AtomicBool::new(false));
        let out = RemoteOutput::prepare_in(remote(url), force, cancel).unwrap();
        let _ = std::fs::remove_dir_all(&out.local);
        std::fs::rename(grid, &out.local).unwrap();
        out.finish(&Quiet).unwrap();
    };
    upload(&dataset(dir.path(), 20, 20, 20), false);
    let (text, _, _) = remote(url).get(INDEX_FILE).unwrap().unwrap();
    let root = Index::parse(&text, Path::new(url)).unwrap();
    assert_eq!(root.uploaded_to(), Some(url));
    let page = |n: &str| Ok(remote(url).get(n).unwrap().unwrap().0.to_vec());
    let all = root.listing(Path::new(url), &page).unwrap();
    assert!(!all.pages.is_empty(), "a paged index");
    assert_eq!(all.parts.len(), 400);
    assert!(all.parts.iter().chain(&all.nodes).all(|e| e.etag.is_some()));
    let ds = Dataset::open_remote(remote(url)).unwrap();
    assert_eq!(ds.points(), 400 * 20);
    let read: usize = ds
        .parts()
        .unwrap()
        .iter()
        .map(|p| p.read_level(0, &[0, 1, 2]).unwrap().len())
        .sum();
    assert_eq!(read, 400 * 20);
    let before = listed();
    assert!(
        before.iter().any(|n| n.contains("/pages-0/page-")),
        "{before:?}"
    );

    // Replaced (`--force`) by a dataset of one page: nothing of the old one is
    // left, its pages included.
    let small = dir.path().join("small");
    std::fs::create_dir(&small).unwrap();
    upload(&dataset(&small, 2, 2, 20), true);
    let after = listed();
    assert!(
        after.iter().all(|n| !n.contains("/pages-")),
        "old pages left: {after:?}"
    );
    assert_eq!(Dataset::open_remote(remote(url)).unwrap().part_count(), 4);
}
