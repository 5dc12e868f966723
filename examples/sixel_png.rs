//! Encodes a PNG with pcimg's sixel encoder and writes the sixel string to stdout:
//! `cargo run --release --example sixel_png -- frame.png > frame.six` (then, for
//! example, `convert frame.six check.png` or `cat frame.six` in a sixel terminal).

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: sixel_png FILE.png"))?;
    let img = image::open(&path)?.to_rgba8();
    let t = std::time::Instant::now();
    let s = pcimg::term::sixel::encode(img.as_raw(), img.width(), img.height())?;
    eprintln!(
        "{}×{}: {} bytes in {:.2} ms",
        img.width(),
        img.height(),
        s.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    print!("{s}");
    Ok(())
}
