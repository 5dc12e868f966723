//! `pcimg preview`: one frame printed inline in the terminal, for a quick look over
//! SSH.

use super::view::{self, ViewArgs};
use crate::store::Dataset;
use crate::term::{self, Protocol};
use crate::tui::protocol::Graphics;
use std::io::IsTerminal;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Image protocol: auto, kitty, sixel, iterm or halfblocks.
    #[arg(long, default_value = "auto")]
    pub protocol: Protocol,
    /// Width in terminal columns (default: the terminal's width).
    #[arg(long)]
    pub cols: Option<u16>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    // The dataset first: a wrong path is the error to report, terminal or not.
    let ds = Arc::new(Dataset::open(&a.view.path)?);
    if !std::io::stdout().is_terminal() {
        anyhow::bail!(
            "stdout is not a terminal, so there is nowhere to draw: use `pcimg render {} -o frame.png` for a file",
            a.view.path.display()
        );
    }
    // Auto is decided from the environment, as the inspector decides it: never
    // by asking the terminal (one that does not answer would hang the command).
    let protocol = match crate::tui::protocol::choose(
        a.protocol,
        &crate::tui::protocol::TerminalEnv::from_process(),
    ) {
        Graphics::Kitty => Protocol::Kitty,
        Graphics::Sixel => Protocol::Sixel,
        Graphics::Iterm2 => Protocol::Iterm,
        Graphics::Halfblocks => Protocol::Halfblocks,
    };
    let cam = view::camera_for(&a.view, &ds)?;
    let (cols, rows, px) = term::terminal_pixels();
    let cols = a.cols.unwrap_or(cols).max(10);
    let rows = rows.saturating_sub(3).max(5);
    // Cell size from the terminal when it says, else 8×16 pixels.
    let (cw, ch) = px
        .map(|(w, h)| (w / cols.max(1) as u32, h / (rows + 3) as u32))
        .filter(|&(w, h)| w > 0 && h > 0)
        .unwrap_or((8, 16));
    let (w, h) = if protocol == Protocol::Halfblocks {
        (cols as u32, rows as u32 * 2)
    } else {
        (cols as u32 * cw, rows as u32 * ch)
    };
    let (frame, report) = view::render_once(ds, &a.view, &cam, w, h)?;
    term::print_frame(&frame, protocol, cols, rows)?;
    println!("{}", view::describe(&report));
    Ok(())
}
