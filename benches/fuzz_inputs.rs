//! A mutation fuzzer for `convert` and the part reader, needing no nightly
//! toolchain: mutates seed files (bytes flipped, set to delimiters and digits,
//! ranges deleted, repeated or cut off, integer fields set to extremes), converts
//! each result with small chunks and small memory budgets (a `.tif` seed, a
//! dataset part, is opened and read level by level instead), and reports every
//! panic, and every failed conversion that left its output or a temporary file
//! behind; panics of the `las`/`laz` decoders that pcimg contains (and reports as
//! errors) are counted apart. The cases are `tests/common/fuzz.rs`'s, which
//! `tests/fuzz.rs` runs a few hundred of in CI.
//!
//! ```text
//! cargo run --release --example fuzz_inputs -- [--iterations 2000] [--seed 1]
//!     [--save DIR] [--only CASE] [SEED_FILE...]
//! ```
//! Without seed files it uses built-in ones of every format (3,000 points each).
//! A seed file's extension picks its reader (`.xyz .csv .pts .ply .las .laz .pcd
//! .e57 .tif`).
//! Cases that go wrong are saved to `--save`. An abort (an allocation the
//! process cannot have) ends the run before its case is saved: `--only CASE`
//! runs that case of the same `--seed` again, prints its options and saves it.
//!
//! The fast mode (`--kind`) is for runs of a million cases per input (issue 39;
//! `bash bench/fuzz.sh` runs every kind): small seeds of one kind, mutated and
//! given to its reader or parser alone, in process, with no conversion
//! (`tests/common/fuzz_fast.rs`):
//!
//! ```text
//! cargo run --release --example fuzz_inputs -- --kind text|ply|las|pcd|e57|part|index|http
//!     [--iterations 1000000] [--seed 1] [--threads 1] [--save DIR] [--only CASE]
//! ```
//! It ends with one line, `RESULT kind cases accepted refused panics contained
//! unnamed broken left_behind seconds`, and exits 1 where any case failed.
//! `--threads`: the rayon threads the readers parse with (the run itself is
//! one thread). An abort (an allocation refused, a stack overflow) prints the
//! case it happened in before the process ends.
use anyhow::Context;
use pcimg::synth::Rng;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

#[path = "../tests/common/fuzz.rs"]
mod fuzz;
use fuzz::Outcome;

/// The last panic's place and message, from the hook.
static PANIC: Mutex<Option<String>> = Mutex::new(None);

fn main() -> anyhow::Result<()> {
    let mut iterations = 2000u64;
    let mut seed = 1u64;
    let mut save: Option<PathBuf> = None;
    let mut only: Option<u64> = None;
    let mut files = Vec::new();
    let mut kind: Option<fuzz::fast::Kind> = None;
    let mut threads = 1usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--iterations" => iterations = args.next().context("--iterations N")?.parse()?,
            "--seed" => seed = args.next().context("--seed N")?.parse()?,
            "--save" => save = Some(args.next().context("--save DIR")?.into()),
            "--only" => only = Some(args.next().context("--only CASE")?.parse()?),
            "--kind" => {
                let k = args.next().context("--kind KIND")?;
                kind = Some(fuzz::fast::Kind::parse(&k).with_context(|| {
                    format!("--kind {k}: one of text ply las pcd e57 part index http")
                })?);
            }
            "--threads" => threads = args.next().context("--threads N")?.parse()?,
            _ => files.push(PathBuf::from(a)),
        }
    }
    if let Some(kind) = kind {
        return fast(kind, iterations, seed, threads, save.as_deref(), only);
    }
    let started = std::time::Instant::now();
    let dir = tempfile::tempdir()?;
    let seeds: Vec<(Vec<u8>, String)> = if files.is_empty() {
        fuzz::seeds(dir.path(), 3000)?
    } else {
        files
            .iter()
            .map(|p| {
                let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("xyz");
                let data = std::fs::read(p).with_context(|| p.display().to_string())?;
                Ok((data, ext.to_string()))
            })
            .collect::<anyhow::Result<_>>()?
    };
    std::panic::set_hook(Box::new(|info| {
        let place = info
            .location()
            .map(|l| format!("{}:{}", l.file(), l.line()))
            .unwrap_or_default();
        *PANIC.lock().unwrap() = Some(place);
    }));
    let mut rng = Rng::new(seed);
    let (mut ok, mut err, mut panics, mut leftovers, mut contained) = (0u64, 0, 0, 0, 0);
    let mut seen = std::collections::BTreeSet::new();
    for it in 0..iterations {
        let (ext, data, work, o) = fuzz::case(&seeds, &mut rng, dir.path(), it);
        let ext = ext.as_str();
        if only.is_some_and(|k| k != it) {
            continue;
        }
        if only.is_some() {
            println!("case {it}: {o:?}");
            keep(save.as_deref(), it, ext, &data)?;
        }
        std::fs::create_dir(&work)?;
        let outcome = fuzz::run(&work, ext, &data, &o)?;
        let report = match outcome {
            Outcome::Accepted => {
                ok += 1;
                None
            }
            Outcome::Refused {
                msg,
                contained: false,
            } => {
                err += 1;
                // Every error should name the file it is about.
                (!msg.contains("in.") && !msg.contains("out.pcimg"))
                    .then(|| format!("an error that names no file: {msg}"))
            }
            Outcome::Refused {
                msg,
                contained: true,
            } => {
                err += 1;
                contained += 1;
                Some(format!("a decoder panicked, reported as: {msg}"))
            }
            Outcome::Panicked(msg) => {
                panics += 1;
                let place = PANIC.lock().unwrap().take().unwrap_or_default();
                Some(format!("panic at {place}: {msg}"))
            }
            Outcome::LeftBehind(left) => {
                leftovers += 1;
                Some(format!("a failed conversion left {left:?}"))
            }
        };
        if let Some(r) = report {
            // Each kind of failure once (case numbers and paths vary).
            let key = r.replace(&*work.to_string_lossy(), "");
            if seen.insert(key) {
                println!("case {it} (.{ext}): {r}");
            }
            keep(save.as_deref(), it, ext, &data)?;
        }
        std::fs::remove_dir_all(&work)?;
        if it % 1000 == 999 {
            eprintln!(
                "{} cases, {panics} panics, {leftovers} left files behind",
                it + 1
            );
        }
    }
    println!(
        "{iterations} cases: {ok} accepted, {err} refused, {panics} panics, {leftovers} left \
         files behind; {contained} decoder panics contained ({} distinct reports)",
        seen.len()
    );
    println!(
        "{:.1} cases/s",
        iterations as f64 / started.elapsed().as_secs_f64()
    );
    if panics + leftovers > 0 {
        std::process::exit(1);
    }
    Ok(())
}

/// Copies a case that went wrong into `save`, if given.
fn keep(save: Option<&Path>, it: u64, ext: &str, data: &[u8]) -> anyhow::Result<()> {
    if let Some(s) = save {
        std::fs::create_dir_all(s)?;
        std::fs::write(s.join(format!("case{it}.{ext}")), data)?;
    }
    Ok(())
}

/// The case running now, for the abort handler.
static CURRENT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// On SIGABRT (an allocation refused, a stack overflow): writes the case that
/// was running, with async-signal-safe calls only; the abort then goes on.
extern "C" fn on_abort(_: libc::c_int) {
    let mut buf = [0u8; 64];
    let head = b"fuzz_inputs: aborted in case ";
    buf[..head.len()].copy_from_slice(head);
    let mut n = CURRENT.load(std::sync::atomic::Ordering::Relaxed);
    let mut digits = [0u8; 20];
    let mut k = 0;
    loop {
        digits[k] = b'0' + (n % 10) as u8;
        k += 1;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    let mut at = head.len();
    for d in digits[..k].iter().rev() {
        buf[at] = *d;
        at += 1;
    }
    buf[at] = b'\n';
    // SAFETY: write(2) is async-signal-safe; the buffer lives on this stack.
    unsafe {
        libc::write(2, buf.as_ptr().cast(), at + 1);
    }
}

/// The fast mode: `iterations` cases of one input kind, each given to its
/// reader or parser alone (`--only`: case `only` alone, saved to `save`).
fn fast(
    kind: fuzz::fast::Kind,
    iterations: u64,
    seed: u64,
    threads: usize,
    save: Option<&Path>,
    only: Option<u64>,
) -> anyhow::Result<()> {
    use fuzz::fast::{Fuzzer, Tally};
    use std::sync::atomic::Ordering;
    // SAFETY: installs a handler that only makes async-signal-safe calls.
    unsafe {
        libc::signal(libc::SIGABRT, on_abort as *const () as libc::sighandler_t);
    }
    fuzz::fast::install_panic_hook();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let dir = tempfile::tempdir()?;
    let mut fuzzer = Fuzzer::new(kind, dir.path())?;
    let mut rng = Rng::new(seed);
    let mut tally = Tally::default();
    let mut seen = std::collections::BTreeSet::new();
    let started = std::time::Instant::now();
    let mut slowest = (0.0f64, 0u64);
    for it in 0..iterations {
        let case = fuzzer.case(&mut rng);
        if only.is_some_and(|k| k != it) {
            continue;
        }
        if only.is_some() {
            println!(
                "case {it}: seed {} (.{}), {:?}, mode {}, faults {:?}",
                case.seed, case.ext, case.read, case.mode, case.faults
            );
            keep_fast(save, kind, it, &case)?;
        }
        CURRENT.store(it, Ordering::Relaxed);
        let t = std::time::Instant::now();
        let verdict = pool.install(|| fuzzer.run(&case));
        let took = t.elapsed().as_secs_f64();
        if took > slowest.0 {
            slowest = (took, it);
        }
        tally.record(&verdict);
        if only.is_some() {
            println!("case {it}: {verdict:?}");
        }
        if verdict.is_failure() {
            let report = format!("{verdict:?}");
            // Each kind of failure once (messages name cases and paths).
            let key: String = report
                .replace(&*dir.path().to_string_lossy(), "")
                .chars()
                .take(160)
                .collect();
            if seen.insert(key) {
                println!("case {it} (.{}): {report}", case.ext);
            }
            keep_fast(save, kind, it, &case)?;
        }
        if (it + 1) % 50_000 == 0 {
            let s = started.elapsed().as_secs_f64();
            eprintln!(
                "{}: {} cases, {} failures, {:.0} cases/s",
                kind.name(),
                it + 1,
                tally.failures(),
                (it + 1) as f64 / s
            );
        }
    }
    let secs = started.elapsed().as_secs_f64();
    println!("slowest case: {} ({:.3} s)", slowest.1, slowest.0);
    println!(
        "RESULT {} {} {} {} {} {} {} {} {} {secs:.1}",
        kind.name(),
        tally.cases,
        tally.accepted,
        tally.refused,
        tally.panics,
        tally.contained,
        tally.unnamed,
        tally.broken,
        tally.left_behind,
    );
    if tally.failures() > 0 {
        std::process::exit(1);
    }
    Ok(())
}

/// Copies a fast case that went wrong into `save`, if given (a remote case as
/// its faults, in text).
fn keep_fast(
    save: Option<&Path>,
    kind: fuzz::fast::Kind,
    it: u64,
    case: &fuzz::fast::Case,
) -> anyhow::Result<()> {
    if let Some(s) = save {
        std::fs::create_dir_all(s)?;
        let name = format!("{}-case{it}.{}", kind.name(), case.ext);
        if kind == fuzz::fast::Kind::Http {
            std::fs::write(s.join(name + ".txt"), format!("{:?}\n", case.faults))?;
        } else {
            std::fs::write(s.join(name), &case.data)?;
        }
    }
    Ok(())
}
