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
    /// Width in terminal columns, at least 10 (default, and at most: the
    /// terminal's width).
    #[arg(long, value_parser = clap::value_parser!(u16).range(10..))]
    pub cols: Option<u16>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    // The dataset first: a wrong path is the error to report, terminal or not.
    let ds = Arc::new(Dataset::open(&a.view.path)?);
    if let Some(h) = &ds.hint {
        note!("{h}");
    }
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
    if a.view.print_camera {
        note!("{}", cam.to_json());
    }
    let (term_cols, term_rows, px) = term::terminal_pixels();
    let (cols, rows, w, h) = frame_size((term_cols, term_rows), px, a.cols, protocol);
    let (frame, report) = view::render_once(ds, &a.view, &cam, w, h)?;
    term::print_frame(&frame, protocol, cols, rows)?;
    super::print_out(&format!("{}\n", view::describe(&report)))?;
    Ok(())
}

/// The picture in cells and pixels: `want` columns (the terminal's width when
/// not given, never wider, at least 10) by the terminal's rows less three for the
/// report, at the terminal's cell size in pixels (8×16 when it does not say);
/// half-blocks are one pixel wide and two high a cell.
fn frame_size(
    (term_cols, term_rows): (u16, u16),
    px: Option<(u32, u32)>,
    want: Option<u16>,
    protocol: Protocol,
) -> (u16, u16, u32, u32) {
    let (cw, ch) = px
        .map(|(w, h)| (w / term_cols.max(1) as u32, h / term_rows.max(1) as u32))
        .filter(|&(w, h)| w > 0 && h > 0)
        .unwrap_or((8, 16));
    let cols = want.unwrap_or(term_cols).min(term_cols.max(10)).max(10);
    let rows = term_rows.saturating_sub(3).max(5);
    if protocol == Protocol::Halfblocks {
        (cols, rows, cols as u32, rows as u32 * 2)
    } else {
        (cols, rows, cols as u32 * cw, rows as u32 * ch)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_narrow_the_picture_at_the_terminals_cell_size() {
        // 100×40 cells of 10×20 pixels.
        let px = Some((1000, 800));
        assert_eq!(
            frame_size((100, 40), px, None, Protocol::Sixel),
            (100, 37, 1000, 740)
        );
        assert_eq!(
            frame_size((100, 40), px, Some(40), Protocol::Sixel),
            (40, 37, 400, 740)
        );
        // Never wider than the terminal, never narrower than 10 columns.
        assert_eq!(frame_size((100, 40), px, Some(300), Protocol::Kitty).0, 100);
        assert_eq!(frame_size((100, 40), px, Some(3), Protocol::Kitty).0, 10);
        assert_eq!(
            frame_size((100, 40), None, Some(40), Protocol::Halfblocks),
            (40, 37, 40, 74)
        );
        assert_eq!(
            frame_size((100, 40), None, None, Protocol::Iterm),
            (100, 37, 800, 592)
        );
    }
}
