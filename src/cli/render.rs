//! `pcimg render`: one frame of a dataset to a PNG, headless.

use super::view::{self, ViewArgs};
use crate::store::Dataset;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Output PNG (the only format written; its name must end in .png).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Frame width in pixels (1 to 16384).
    #[arg(long, default_value_t = 1280, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub width: u32,
    /// Frame height in pixels (1 to 16384).
    #[arg(long, default_value_t = 720, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: u32,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let png = a
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        anyhow::bail!(
            "-o {}: frames are written as PNG only: name the file NAME.png",
            crate::text::sanitize(&a.output.display().to_string())
        );
    }
    // Ctrl-C, SIGTERM, SIGHUP: nothing half-written stays (a large frame takes
    // seconds to encode).
    let tmp = crate::render::png_temporary(&a.output);
    let _ = ctrlc::set_handler(move || {
        let _ = std::fs::remove_file(&tmp);
        std::process::exit(130);
    });
    let ds = Arc::new(Dataset::open(&a.view.path)?);
    if let Some(h) = &ds.hint {
        note!("{h}");
    }
    let cam = view::camera_for(&a.view, &ds)?;
    if a.view.print_camera {
        note!("{}", cam.to_json());
    }
    let (frame, report) = view::render_once(ds, &a.view, &cam, a.width, a.height)?;
    frame.save_png(&a.output)?;
    note!("{}", view::describe(&report));
    note!(
        "wrote {}",
        crate::text::sanitize(&a.output.display().to_string())
    );
    Ok(())
}
