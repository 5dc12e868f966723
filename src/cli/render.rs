//! `pcimg render`: one frame of a dataset to a PNG, headless.

use super::view::{self, ViewArgs};
use crate::store::Dataset;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    #[arg(long, default_value_t = 720)]
    pub height: u32,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let ds = Arc::new(Dataset::open(&a.view.path)?);
    let cam = view::camera_for(&a.view, &ds)?;
    if a.view.print_camera {
        eprintln!("{}", cam.to_json());
    }
    let (frame, report) = view::render_once(ds, &a.view, &cam, a.width, a.height)?;
    frame.save_png(&a.output)?;
    eprintln!("{}", view::describe(&report));
    eprintln!(
        "wrote {}",
        crate::text::sanitize(&a.output.display().to_string())
    );
    Ok(())
}
