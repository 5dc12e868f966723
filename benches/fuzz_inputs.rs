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
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--iterations" => iterations = args.next().context("--iterations N")?.parse()?,
            "--seed" => seed = args.next().context("--seed N")?.parse()?,
            "--save" => save = Some(args.next().context("--save DIR")?.into()),
            "--only" => only = Some(args.next().context("--only CASE")?.parse()?),
            _ => files.push(PathBuf::from(a)),
        }
    }
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
