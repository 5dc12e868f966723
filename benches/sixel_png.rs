//! Encodes a PNG with pcimg's sixel encoder and writes the sixel string to stdout,
//! with the colour count, bytes and median times of the two steps on stderr:
//!
//! ```sh
//! cargo run --release --example sixel_png -- frame.png [COLOURS] [RUNS] > frame.six
//! ```
//!
//! Then, for example, `convert frame.six check.png` (ImageMagick decodes sixel) or
//! `cat frame.six` in a sixel terminal.

use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: sixel_png FILE.png [COLOURS] [RUNS]"))?;
    let colors = args
        .next()
        .map_or(Ok(pcimg::term::sixel::COLORS), |s| s.parse())?;
    let runs: usize = args.next().map_or(Ok(1), |s| s.parse())?;
    let img = image::open(&path)?.to_rgba8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (mut reduce, mut encode) = (vec![], vec![]);
    let mut out = String::new();
    let mut n = 0;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let q = pcimg::term::palette::reduce(img.as_raw(), colors);
        reduce.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        out = pcimg::term::sixel::encode_indexed(&q, w, h)?;
        encode.push(t.elapsed().as_secs_f64() * 1e3);
        n = q.palette.len();
    }
    eprintln!(
        "{w}×{h}: {n} colours, {} bytes; reduce {:.2} ms, encode {:.2} ms (median of {})",
        out.len(),
        median(reduce),
        median(encode),
        runs.max(1)
    );
    print!("{out}");
    Ok(())
}
