//! A mutation fuzzer for `convert`, needing no nightly toolchain: mutates seed
//! input files (bytes flipped, set to delimiters and digits, ranges deleted,
//! repeated or cut off), converts each result with small chunks and a small
//! memory budget, and reports every panic, and every failed conversion that left
//! its output or a temporary file behind; panics of the `las`/`laz` decoders that
//! pcimg contains (and reports as errors) are counted apart. Inputs that panic
//! are saved to `--save`.
//!
//! ```text
//! cargo run --release --example fuzz_inputs -- [--iterations 2000] [--seed 1]
//!     [--save DIR] [--only CASE] SEED_FILE...
//! ```
//! `--only CASE` runs one case of the same `--seed` again (its options printed and,
//! with `--save`, its input kept): for an abort, which ends the run before the
//! case can be saved.
//! Seed files keep their extension, which picks the reader (`.xyz .csv .pts .ply
//! .las .laz`...); a `.tif` seed is a dataset part, opened and read level by level. Small seeds (a few thousand points) run hundreds a second.
use anyhow::{Context, bail};
use pcimg::convert::{self, ConvertOptions, Partition, Quiet};
use pcimg::ingest::ReadOptions;
use pcimg::store::{Compression, Layout, Part, TileIo};
use pcimg::synth::Rng;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

/// The last panic's message and place, from the hook.
static PANIC: Mutex<Option<String>> = Mutex::new(None);

/// Bytes that steer a text or header parser somewhere new.
const INTERESTING: &[u8] = b"\n\r\t ,;-+.eE0123456789#/\"'nNaiI\x00\xff";

fn main() -> anyhow::Result<()> {
    let mut iterations = 2000u64;
    let mut seed = 1u64;
    let mut save: Option<PathBuf> = None;
    let mut only: Option<u64> = None;
    let mut seeds = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--iterations" => iterations = args.next().context("--iterations N")?.parse()?,
            "--seed" => seed = args.next().context("--seed N")?.parse()?,
            "--save" => save = Some(args.next().context("--save DIR")?.into()),
            "--only" => only = Some(args.next().context("--only CASE")?.parse()?),
            _ => seeds.push(PathBuf::from(a)),
        }
    }
    if seeds.is_empty() {
        bail!("usage: fuzz_inputs [--iterations N] [--seed N] [--save DIR] SEED_FILE...");
    }
    let originals: Vec<(Vec<u8>, String)> = seeds
        .iter()
        .map(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("xyz");
            Ok((
                std::fs::read(p).with_context(|| p.display().to_string())?,
                ext.to_string(),
            ))
        })
        .collect::<anyhow::Result<_>>()?;
    std::panic::set_hook(Box::new(|info| {
        let place = info
            .location()
            .map(|l| format!("{}:{}", l.file(), l.line()))
            .unwrap_or_default();
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        *PANIC.lock().unwrap() = Some(format!("{place}: {msg}"));
    }));
    let dir = tempfile::tempdir()?;
    let mut rng = Rng::new(seed);
    let (mut ok, mut err, mut panics, mut leftovers) = (0u64, 0u64, 0u64, 0u64);
    let mut seen = std::collections::BTreeSet::new();
    let (mut contained, mut seen_contained) = (0u64, std::collections::BTreeSet::new());
    for it in 0..iterations {
        let (orig, ext) = &originals[below(&mut rng, originals.len() as u64) as usize];
        let data = mutate(orig, &mut rng);
        let work = dir.path().join(format!("case{it}"));
        std::fs::create_dir(&work)?;
        let input = work.join(format!("in.{ext}"));
        std::fs::write(&input, &data)?;
        let o = ConvertOptions {
            output: work.join("out.pcimg"),
            force: false,
            memory: [1u64 << 20, 8 << 20, 1 << 30][below(&mut rng, 3) as usize],
            partition: if below(&mut rng, 3) == 0 {
                Partition::Stream
            } else {
                Partition::Spatial
            },
            compression: [Compression::None, Compression::Deflate][below(&mut rng, 2) as usize],
            layout: if below(&mut rng, 4) == 0 {
                Layout::Paper
            } else {
                Layout::Hilbert
            },
            read: ReadOptions {
                // Text: now and then the columns given rather than detected.
                columns: match below(&mut rng, 8) {
                    0 => Some("x y z intensity".into()),
                    1 => Some("x y z _ r g b".into()),
                    2 => Some("_ x y z".into()),
                    _ => None,
                }
                .filter(|_| !matches!(ext.as_str(), "ply" | "las" | "laz" | "tif")),
                skip_invalid: below(&mut rng, 2) == 0,
                chunk_points: [1usize, 7, 500, 4096][below(&mut rng, 4) as usize],
            },
            allow_lossy: below(&mut rng, 2) == 0,
            cancel: Arc::new(AtomicBool::new(false)),
            sample_points: 1000,
            io: TileIo::Buffered,
        };
        if only.is_some_and(|k| k != it) {
            std::fs::remove_dir_all(&work)?;
            continue;
        }
        if only.is_some() {
            println!("case {it}: {o:?}");
            keep(save.as_deref(), it, ext, &data)?;
        }
        let r = std::panic::catch_unwind(|| {
            if ext == "tif" {
                // A dataset part: opened and every level read, as `info` and
                // the viewer do.
                read_part(&input)
            } else {
                convert::convert(&input, &o, &Quiet).map(|_| ())
            }
        });
        match r {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(e)) => {
                err += 1;
                // A panic of a third-party decoder that pcimg caught and
                // reported (`ingest::contain`): not a failure, but worth knowing.
                let msg = format!("{e:#}");
                if msg.contains("failed on corrupt data") || msg.contains("header is corrupt") {
                    contained += 1;
                    if seen_contained.insert(msg.clone()) {
                        println!("case {it} (.{ext}): a decoder panicked, reported as: {msg}");
                    }
                    keep(save.as_deref(), it, ext, &data)?;
                }
                let left: Vec<String> = std::fs::read_dir(&work)?
                    .filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n != input.file_name().unwrap().to_str().unwrap())
                    .collect();
                if !left.is_empty() {
                    leftovers += 1;
                    println!("case {it} (.{ext}): a failed conversion left {left:?}");
                    keep(save.as_deref(), it, ext, &data)?;
                }
            }
            Err(_) => {
                panics += 1;
                let msg = PANIC.lock().unwrap().take().unwrap_or_default();
                if seen.insert(msg.clone()) {
                    println!("case {it} (.{ext}): panic at {msg}");
                }
                keep(save.as_deref(), it, ext, &data)?;
            }
        }
        std::fs::remove_dir_all(&work)?;
    }
    println!(
        "{iterations} cases: {ok} accepted, {err} refused, {panics} panics ({} distinct), \
         {leftovers} left files behind; {contained} decoder panics contained ({} distinct)",
        seen.len(),
        seen_contained.len()
    );
    if panics + leftovers > 0 {
        std::process::exit(1);
    }
    Ok(())
}

/// Opens a part and reads every level of every band (small parts only: one that
/// declares millions of points may legitimately need that much memory).
fn read_part(path: &Path) -> anyhow::Result<()> {
    let part = Part::open(path)?;
    if part.meta.point_count <= 1 << 20 {
        let bands: Vec<usize> = (0..part.bands.len()).collect();
        for level in 0..part.levels.len() {
            part.read_level(level, &bands)?;
        }
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

/// One to eight mutations of `orig`, mostly near its start (where the headers are)
/// or anywhere.
fn mutate(orig: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut d = orig.to_vec();
    let n = 1 + below(rng, 8);
    for _ in 0..n {
        if d.is_empty() {
            d.push(INTERESTING[below(rng, INTERESTING.len() as u64) as usize]);
            continue;
        }
        let len = d.len() as u64;
        // Headers are where most structure is: half the mutations land in the
        // first 512 bytes.
        let at = if below(rng, 2) == 0 {
            below(rng, len.min(512))
        } else {
            below(rng, len)
        } as usize;
        match below(rng, 7) {
            0 => d[at] ^= 1 << below(rng, 8),
            1 => d[at] = INTERESTING[below(rng, INTERESTING.len() as u64) as usize],
            2 => d[at] = below(rng, 256) as u8,
            3 => {
                let k = (1 + below(rng, 64)) as usize;
                d.drain(at..(at + k).min(d.len()));
            }
            4 => {
                let k = (1 + below(rng, 64)) as usize;
                let piece: Vec<u8> = d[at..(at + k).min(d.len())].to_vec();
                let to = below(rng, d.len() as u64) as usize;
                d.splice(to..to, piece);
            }
            5 => d.truncate(at),
            _ => {
                // An integer field (a count, an offset) set to an extreme.
                let v: u32 =
                    [0, 1, 0x7fff_ffff, 0xffff_ffff, 0x8000_0000, 65535][below(rng, 6) as usize];
                let end = (at + 4).min(d.len());
                let bytes = v.to_le_bytes();
                d[at..end].copy_from_slice(&bytes[..end - at]);
            }
        }
    }
    d
}

/// A number below `n` (n >= 1).
fn below(rng: &mut Rng, n: u64) -> u64 {
    rng.next_u64() % n
}
