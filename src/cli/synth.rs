//! `pcimg synth`: writes a deterministic synthetic scan as text, LAS or LAZ, for
//! tests and benchmarks.

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Number of points.
    #[arg(short = 'n', long, default_value_t = 1_000_000)]
    pub points: u64,
    /// Output file: .xyz/.txt (x y z intensity text, the paper's input), .las or
    /// .laz (compressed LAS).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Seed: the same seed and count always give the same points.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Point order: random (generation order, spatially random) or scan (flight
    /// strips and scan lines, neighbours next to each other, like a scanner's file).
    #[arg(long, default_value = "random", value_parser = crate::synth::Order::parse)]
    pub order: crate::synth::Order,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if a.output.exists() && !a.force {
        anyhow::bail!(
            "{}: already exists (use --force to replace it)",
            a.output.display()
        );
    }
    if a.output.is_dir() {
        anyhow::bail!("{}: is a directory", a.output.display());
    }
    if a.points == 0 {
        anyhow::bail!("-n 0: a scan needs at least one point");
    }
    {
        // Ctrl-C: remove the unfinished file, then stop as the signal would.
        let tmp = crate::synth::temp_path(&a.output);
        let _ = ctrlc::set_handler(move || {
            let _ = std::fs::remove_file(&tmp);
            note!("pcimg: interrupted: nothing was written");
            std::process::exit(1);
        });
    }
    let ext = a
        .output
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let t = std::time::Instant::now();
    let bytes = match ext.as_str() {
        "las" | "laz" => crate::synth::write_las_in_order(&a.output, a.points, a.seed, a.order),
        "xyz" | "txt" => crate::synth::write_text_in_order(&a.output, a.points, a.seed, a.order),
        _ => anyhow::bail!(
            "{}: unknown output format (use .xyz, .txt, .las or .laz)",
            a.output.display()
        ),
    }
    .map_err(|e| anyhow::anyhow!("{}: {e}", a.output.display()))?;
    note!(
        "wrote {} points to {} ({}) in {:.1} s",
        crate::text::count(a.points),
        a.output.display(),
        crate::text::bytes(bytes),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
