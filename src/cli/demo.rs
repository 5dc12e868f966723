//! `pcimg demo`: builds a synthetic dataset in a temporary directory and opens the
//! inspector on it (or, without a terminal, prints its report).

use crate::store::{self, WriteOptions};
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Points in the synthetic scan.
    #[arg(short = 'n', long, default_value_t = 2_000_000)]
    pub points: u64,
    /// Keep the dataset in this directory instead of a temporary one.
    #[arg(long)]
    pub keep: Option<PathBuf>,
    /// Image protocol of the inspector: auto, kitty, sixel, iterm or halfblocks.
    #[arg(long, default_value = "auto")]
    pub protocol: crate::term::Protocol,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    super::inspect::no_device_select();
    let interactive = super::inspect::have_terminal();
    let tmp;
    let dir = match &a.keep {
        Some(d) => {
            std::fs::create_dir_all(d)?;
            d.clone()
        }
        None => {
            tmp = std::env::temp_dir().join(format!("pcimg-demo-{}", std::process::id()));
            std::fs::create_dir_all(&tmp)?;
            tmp.clone()
        }
    };
    let path = dir.join("demo.tif");
    eprintln!(
        "pcimg demo: generating {} synthetic points…",
        crate::text::count(a.points)
    );
    let t = std::time::Instant::now();
    let pts = crate::synth::scene(a.points, 1);
    let opts = WriteOptions {
        source: Some("pcimg synth".into()),
        ..Default::default()
    };
    let s = store::write_part(&path, &pts, &opts)?;
    eprintln!(
        "pcimg demo: wrote {} ({}) in {:.2} s",
        path.display(),
        crate::text::bytes(s.bytes),
        t.elapsed().as_secs_f64()
    );
    let ds = store::Dataset::open(&path)?;
    let shown = if interactive {
        let mut args = super::inspect::defaults(&path);
        args.protocol = a.protocol;
        super::inspect::open(std::sync::Arc::new(ds), &args)
    } else {
        print!(
            "{}",
            super::info::render_text(&super::info::report(&ds, false))
        );
        match &a.keep {
            Some(_) => println!(
                "(stdout is not a terminal, so the inspector did not open: look at the dataset with \
                 `pcimg render {0} -o frame.png` or `pcimg preview {0}`)",
                path.display()
            ),
            None => println!(
                "(stdout is not a terminal, so the inspector did not open. Keep the dataset with \
                 `pcimg demo --keep DIR`, then look at it with `pcimg render DIR/demo.tif -o frame.png` \
                 or `pcimg preview DIR/demo.tif`.)"
            ),
        }
        Ok(())
    };
    if a.keep.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    shown
}
