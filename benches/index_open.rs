//! Opening a dataset and drawing its first frame (issue 44): the time, requests
//! and bytes to open it (its index) and to load the first frame of the whole of
//! it (a top view, 1280 × 720, the viewer's automatic point budget, the selected
//! tiles read on 8 threads as the viewer's loaders do; no rasterizing), locally
//! and from object storage with a latency per request.
//!
//! ```text
//! cargo run --release --example index_open -- DATASET [--latency-ms 50] [--reps 3]
//! ```
//!
//! Object storage is object_store's in-memory store behind `ThrottledStore`
//! (`--latency-ms` before every GET, as the remote tests use): every file of the
//! dataset is put there first (not timed). Each run opens the dataset afresh
//! under a new URL (no cache from the run before). Prints one line per run.
use object_store::memory::InMemory;
use object_store::throttle::{ThrottleConfig, ThrottledStore};
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};
use pcimg::camera::{self, Camera};
use pcimg::lod::{self, LodMode};
use pcimg::remote::Remote;
use pcimg::store::Dataset;
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Loads the first frame of `ds` (a top view of the whole, or with `street`
/// of a 1 km square at its centre): points and tiles.
fn first_frame(ds: &Dataset, street: bool) -> Result<(u64, usize), Box<dyn std::error::Error>> {
    let all = ds.bounds();
    let c = all.center();
    let target = if street {
        pcimg::points::Bounds {
            min: [c[0] - 500.0, c[1] - 500.0, all.min[2]],
            max: [c[0] + 500.0, c[1] + 500.0, all.max[2]],
        }
    } else {
        all
    };
    let mut cam = Camera::fit(&target);
    cam.apply_view(&camera::parse_view("0,-89")?);
    cam.set_clip_from_bounds(&all);
    let budget = lod::budget_for_pixels(1280, 720, lod::DEFAULT_BUDGET_CAP);
    let sel = lod::select(ds, &cam, 1280, 720, LodMode::View { budget }, 8 << 30);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(8).build()?;
    let points = pool.install(|| {
        sel.tiles
            .par_iter()
            .map(|t| -> Result<u64, pcimg::store::StoreError> {
                let p = ds.try_part(t.part)?;
                let bands = p.band_indices(&["x", "y", "z"])?;
                Ok(p.read_tiles(t.level, &[t.tile], &bands)?.len() as u64)
            })
            .sum::<Result<u64, _>>()
    })?;
    Ok((points, sel.tiles.len()))
}

/// Every file under `dir` into an in-memory store under `prefix`.
fn upload(dir: &Path, prefix: &str) -> Result<InMemory, Box<dyn std::error::Error>> {
    let mem = InMemory::new();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d)? {
            let p = e?.path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            let rel = p.strip_prefix(dir)?.to_string_lossy().replace('\\', "/");
            let loc = object_store::path::Path::from(format!("{prefix}/{rel}"));
            rt.block_on(mem.put(&loc, PutPayload::from(std::fs::read(&p)?)))?;
        }
    }
    Ok(mem)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut latency, mut reps, mut path) = (50u64, 3usize, None);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--latency-ms" => latency = it.next().ok_or("--latency-ms MS")?.parse()?,
            "--reps" => reps = it.next().ok_or("--reps N")?.parse()?,
            p => path = Some(p.to_string()),
        }
    }
    let path = path.ok_or("usage: index_open DATASET [--latency-ms 50] [--reps 3]")?;
    let dir = Path::new(&path);
    for rep in 0..reps {
        let t = Instant::now();
        let ds = Dataset::open(dir)?;
        let open = t.elapsed();
        let (points, tiles) = first_frame(&ds, false)?;
        let frame = t.elapsed();
        let (pages, loaded) = ds.index_pages();
        let t = Instant::now();
        let (spoints, stiles) = first_frame(&ds, true)?;
        let street = t.elapsed();
        let (_, sloaded) = ds.index_pages();
        println!(
            "local  run {rep}: open {:.1} ms, first frame {:.1} ms; {} parts, index {} bytes, \
             {loaded} of {pages} pages read; {points} points from {tiles} tiles; then a 1 km \
             square: {:.1} ms, {} more pages, {spoints} points from {stiles} tiles",
            open.as_secs_f64() * 1e3,
            frame.as_secs_f64() * 1e3,
            ds.part_count(),
            ds.index_bytes.unwrap_or(0),
            street.as_secs_f64() * 1e3,
            sloaded - loaded,
        );
    }
    // Parsing the index: the root, then every page (what version 1 parsed
    // before its first frame, in one document).
    let t = Instant::now();
    let text = std::fs::read(dir.join(pcimg::store::dataset::index::INDEX_FILE))?;
    let index = pcimg::store::dataset::index::Index::parse(&text, dir)?;
    let root_ms = t.elapsed().as_secs_f64() * 1e3;
    let page_bytes = std::cell::Cell::new(0u64);
    let read = |name: &str| {
        let b = std::fs::read(dir.join(name))
            .map_err(|e| pcimg::store::StoreError::new(&dir.join(name), e.to_string()))?;
        page_bytes.set(page_bytes.get() + b.len() as u64);
        Ok(b)
    };
    let listing = index.listing(dir, &read)?;
    let all_ms = t.elapsed().as_secs_f64() * 1e3;
    let pages = listing.pages.len().max(1);
    println!(
        "parse: root {} bytes in {root_ms:.2} ms; then {} more pages, {} bytes, in {:.1} ms \
         ({:.2} ms a page, {:.0} MB/s)",
        text.len(),
        listing.pages.len(),
        page_bytes.get(),
        all_ms - root_ms,
        (all_ms - root_ms) / pages as f64,
        page_bytes.get() as f64 / 1e6 / ((all_ms - root_ms) / 1e3).max(1e-9),
    );
    let t = Instant::now();
    let mem = upload(dir, "ds")?;
    eprintln!("(uploaded to memory in {:.1} s)", t.elapsed().as_secs_f64());
    let cfg = ThrottleConfig {
        wait_get_per_call: Duration::from_millis(latency),
        ..Default::default()
    };
    let store: Arc<dyn ObjectStore> = Arc::new(ThrottledStore::new(mem, cfg));
    for rep in 0..reps {
        let url = format!("memory://run{rep}/ds");
        let remote = Arc::new(Remote::with_store(store.clone(), "ds", &url));
        let t = Instant::now();
        let ds = Dataset::open_remote(remote.clone())?;
        let open = t.elapsed();
        let (r0, b0) = (
            remote.requests.load(Ordering::Relaxed),
            remote.received.load(Ordering::Relaxed),
        );
        let (points, tiles) = first_frame(&ds, false)?;
        let frame = t.elapsed();
        let (r1, b1) = (
            remote.requests.load(Ordering::Relaxed),
            remote.received.load(Ordering::Relaxed),
        );
        let (pages, loaded) = ds.index_pages();
        let page_bytes = ds.pages_fetched().1;
        let t = Instant::now();
        let (spoints, stiles) = first_frame(&ds, true)?;
        let street = t.elapsed();
        let (r2, b2) = (
            remote.requests.load(Ordering::Relaxed),
            remote.received.load(Ordering::Relaxed),
        );
        let (_, sloaded) = ds.index_pages();
        println!(
            "remote run {rep} ({latency} ms a request): open {:.1} ms, {r0} request(s), {b0} bytes; \
             first frame {:.1} ms, {r1} requests, {b1} bytes in all ({} pages of {pages} read, \
             {page_bytes} bytes of them); {points} points from {tiles} tiles; then a 1 km square: \
             {:.1} ms, {} requests, {} bytes, {} more pages ({} bytes); {spoints} points from \
             {stiles} tiles",
            open.as_secs_f64() * 1e3,
            frame.as_secs_f64() * 1e3,
            loaded,
            street.as_secs_f64() * 1e3,
            r2 - r1,
            b2 - b1,
            sloaded - loaded,
            ds.pages_fetched().1 - page_bytes,
        );
    }
    Ok(())
}
