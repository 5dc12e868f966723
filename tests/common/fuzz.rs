//! The mutation fuzzer's cases, shared by `benches/fuzz_inputs.rs` (long runs)
//! and `tests/fuzz.rs` (a short, deterministic run in CI): seed files of every
//! input format and a dataset part, their mutations, the options each case
//! converts with, and what became of it. The fast mode for runs of a million
//! cases per input (each input's reader or parser alone, in process) is
//! [`fast`].

use pcimg::convert::{self, ConvertOptions, Partition, Quiet};
use pcimg::ingest::ReadOptions;
use pcimg::store::{Compression, Layout, Part, TileIo};
use pcimg::synth::Rng;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

#[path = "fuzz_fast.rs"]
pub mod fast;

/// Bytes that steer a text or header parser somewhere new.
const INTERESTING: &[u8] = b"\n\r\t ,;-+.eE0123456789#/\"'nNaiI\x00\xff";

/// A number below `n` (n ≥ 1).
pub fn below(rng: &mut Rng, n: u64) -> u64 {
    rng.next_u64() % n
}

/// What became of one case.
pub enum Outcome {
    /// Converted (or, for a part, opened and read).
    Accepted,
    /// Refused with an error; `contained`: the error reports a panic of the
    /// `las`/`laz` decoders that pcimg caught (`ingest::contain`).
    Refused { msg: String, contained: bool },
    /// A panic reached the caller: a bug.
    Panicked(String),
    /// A failed conversion left these files beside its input: a bug.
    LeftBehind(Vec<String>),
}

/// Small seed files, `n` points each: text (`.xyz`), CSV with a header, PTS with
/// a count line, ASCII and binary (both byte orders) PLY with a face element,
/// LAS, LAZ, PCD (ascii, binary, binary_compressed), E57 (floats in one scan,
/// scaled integers in two), and a dataset part (`.tif`, from the text).
/// Written under `dir`.
pub fn seeds(dir: &Path, n: u64) -> anyhow::Result<Vec<(Vec<u8>, String)>> {
    let xyz = dir.join("seed.xyz");
    pcimg::synth::write_text(&xyz, n, 1)?;
    let text = std::fs::read_to_string(&xyz)?;
    let rows: Vec<Vec<&str>> = text
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    let mut csv = String::from("x,y,z,intensity\n");
    let mut pts = format!("{}\n", rows.len());
    for r in &rows {
        csv += &format!("{}\n", r.join(","));
        pts += &format!("{} 10 20 30\n", r.join(" "));
    }
    let mut out = vec![
        (text.clone().into_bytes(), "xyz".to_string()),
        (csv.into_bytes(), "csv".to_string()),
        (pts.into_bytes(), "pts".to_string()),
    ];
    let xyz_of = |r: &Vec<&str>| -> [f64; 3] {
        [0, 1, 2].map(|a| r.get(a).and_then(|v| v.parse().ok()).unwrap_or(0.0))
    };
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let mut d = format!(
            "ply\nformat {format} 1.0\ncomment seed\nelement vertex {}\nproperty float x\n\
             property float y\nproperty double z\nproperty uchar red\nproperty uchar green\n\
             property uchar blue\nelement face 1\nproperty list uchar int vertex_indices\n\
             end_header\n",
            rows.len()
        )
        .into_bytes();
        // Binary values in the file's byte order.
        let big = format == "binary_big_endian";
        let put = |d: &mut Vec<u8>, mut b: Vec<u8>| {
            if big {
                b.reverse();
            }
            d.extend(b);
        };
        for (i, r) in rows.iter().enumerate() {
            let [x, y, z] = xyz_of(r);
            let c = [(i % 256) as u8, 7, 9];
            if format == "ascii" {
                d.extend(format!("{x} {y} {z} {} {} {}\n", c[0], c[1], c[2]).bytes());
            } else {
                put(&mut d, (x as f32).to_le_bytes().to_vec());
                put(&mut d, (y as f32).to_le_bytes().to_vec());
                put(&mut d, z.to_le_bytes().to_vec());
                d.extend(c);
            }
        }
        if format == "ascii" {
            d.extend(b"3 0 1 2\n");
        } else {
            d.push(3);
            for v in [0i32, 1, 2] {
                put(&mut d, v.to_le_bytes().to_vec());
            }
        }
        out.push((d, "ply".to_string()));
    }
    for ext in ["las", "laz"] {
        let p = dir.join(format!("seed.{ext}"));
        pcimg::synth::write_las(&p, n, 2)?;
        out.push((std::fs::read(&p)?, ext.to_string()));
    }
    use pcimg::synth_formats::{PcdData, write_e57, write_pcd};
    for data in [PcdData::Ascii, PcdData::Binary, PcdData::Compressed] {
        let p = dir.join("seed.pcd");
        write_pcd(&p, n, 3, data)?;
        out.push((std::fs::read(&p)?, "pcd".to_string()));
    }
    for (scaled, scans) in [(false, 1), (true, 2)] {
        let p = dir.join("seed.e57");
        write_e57(&p, n, 4, scaled, scans)?;
        out.push((std::fs::read(&p)?, "e57".to_string()));
    }
    let part = dir.join("seed.tif");
    let o = ConvertOptions {
        compression: Compression::Deflate,
        memory: 1 << 30,
        ..options(&mut Rng::new(0), "xyz", &part)
    };
    convert::convert(&xyz, &o, &Quiet)?;
    out.push((std::fs::read(&part)?, "tif".to_string()));
    // And a LERC one (lossy coordinates): damaged LERC blobs are read too.
    let lerc = dir.join("seed-lerc.tif");
    let o = ConvertOptions {
        compression: Compression::LercZstd,
        max_error: Some(0.004),
        memory: 1 << 30,
        ..options(&mut Rng::new(0), "xyz", &lerc)
    };
    convert::convert(&xyz, &o, &Quiet)?;
    out.push((std::fs::read(&lerc)?, "tif".to_string()));
    Ok(out)
}

/// One to eight mutations of `orig`: half of them in its first 512 bytes (where
/// the headers are), the rest anywhere.
pub fn mutate(orig: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut d = orig.to_vec();
    let n = 1 + below(rng, 8);
    for _ in 0..n {
        if d.is_empty() {
            d.push(INTERESTING[below(rng, INTERESTING.len() as u64) as usize]);
            continue;
        }
        let len = d.len() as u64;
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
                d[at..end].copy_from_slice(&v.to_le_bytes()[..end - at]);
            }
        }
    }
    d
}

/// The options a case converts with: small chunks and budgets (so inputs of a
/// few thousand points make many chunks and parts), both partitions and layouts,
/// text columns now and then given rather than detected.
pub fn options(rng: &mut Rng, ext: &str, output: &Path) -> ConvertOptions {
    ConvertOptions {
        output: output.to_path_buf(),
        force: false,
        memory: [1u64 << 20, 8 << 20, 1 << 30][below(rng, 3) as usize],
        partition: if below(rng, 3) == 0 {
            Partition::Stream
        } else {
            Partition::Spatial
        },
        compression: [
            Compression::None,
            Compression::Deflate,
            Compression::Lerc,
            Compression::LercDeflate,
            Compression::LercZstd,
        ][below(rng, 5) as usize],
        zstd_level: None,
        // The LERC codecs' coordinate bound (ignored by the others): lossless,
        // or a few millimetres.
        max_error: [None, Some(0.004)][below(rng, 2) as usize],
        precision: None,
        layout: if below(rng, 4) == 0 {
            Layout::Paper
        } else {
            Layout::Hilbert
        },
        read: ReadOptions {
            columns: match below(rng, 8) {
                0 => Some("x y z intensity".into()),
                1 => Some("x y z _ r g b".into()),
                2 => Some("_ x y z".into()),
                _ => None,
            }
            .filter(|_| !matches!(ext, "ply" | "las" | "laz" | "pcd" | "e57" | "tif")),
            skip_invalid: below(rng, 2) == 0,
            chunk_points: [1usize, 7, 500, 4096][below(rng, 4) as usize],
            region: None,
        },
        allow_lossy: below(rng, 2) == 0,
        cancel: Arc::new(AtomicBool::new(false)),
        sample_points: 1000,
        io: TileIo::Buffered,
        on_part: None,
    }
}

/// One case drawn from `seeds`: its extension, its mutated bytes, its directory
/// (`dir/caseN`, not yet made) and the options it converts with. Drawn the same
/// way whether or not it is then run, so a run's case `it` can be replayed.
pub fn case(
    seeds: &[(Vec<u8>, String)],
    rng: &mut Rng,
    dir: &Path,
    it: u64,
) -> (String, Vec<u8>, std::path::PathBuf, ConvertOptions) {
    let (orig, ext) = &seeds[below(rng, seeds.len() as u64) as usize];
    let data = mutate(orig, rng);
    let work = dir.join(format!("case{it}"));
    let o = options(rng, ext, &work.join("out.pcimg"));
    (ext.clone(), data, work, o)
}

/// Runs one case in the empty directory `work`: `data` written as `in.EXT`, then
/// converted with `o` (whose output lies in `work`), or for a part opened and
/// read level by level.
pub fn run(work: &Path, ext: &str, data: &[u8], o: &ConvertOptions) -> anyhow::Result<Outcome> {
    let input = work.join(format!("in.{ext}"));
    std::fs::write(&input, data)?;
    let r = std::panic::catch_unwind(|| {
        if ext == "tif" {
            read_part(&input)
        } else {
            convert::convert(&input, o, &Quiet).map(|_| ())
        }
    });
    Ok(match r {
        Ok(Ok(())) => Outcome::Accepted,
        Ok(Err(e)) => {
            let left: Vec<String> = std::fs::read_dir(work)?
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| *n != format!("in.{ext}"))
                .collect();
            if left.is_empty() {
                let msg = format!("{e:#}");
                let contained =
                    msg.contains("failed on corrupt data") || msg.contains("header is corrupt");
                Outcome::Refused { msg, contained }
            } else {
                Outcome::LeftBehind(left)
            }
        }
        Err(payload) => Outcome::Panicked(
            payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_default(),
        ),
    })
}

/// Opens a part and reads every level of every band, as `info` and the viewer
/// do (small parts only: one that declares millions of points may legitimately
/// need that much memory).
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
