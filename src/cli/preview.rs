//! `pcimg preview`: one frame printed inline in the terminal, for a quick look over
//! SSH.

use super::view::{self, ViewArgs};
use crate::term::symbols::SymbolSet;
use crate::term::{self, Protocol};
use std::io::IsTerminal;
use std::sync::Arc;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub view: ViewArgs,
    /// Image protocol: auto, kitty, sixel, iterm or text (symbols in colour,
    /// for terminals and links without images).
    #[arg(long, default_value = "auto")]
    pub protocol: Protocol,
    /// Symbols of the text protocol: half (blocks), quadrants, sextants,
    /// octants or braille. Default: sextants where the terminal draws them
    /// itself (kitty, WezTerm, foot, Ghostty), else quadrants (every font);
    /// `pcimg doctor` says which.
    #[arg(long)]
    pub symbols: Option<SymbolSet>,
    /// Width in terminal columns, at least 10 (default, and at most: the
    /// terminal's width).
    #[arg(long, value_parser = clap::value_parser!(u16).range(10..))]
    pub cols: Option<u16>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    // The dataset first: a wrong path is the error to report, terminal or not.
    a.view.cache.apply()?;
    let ds = Arc::new(super::remote::open_for_view(&a.view.path, &a.view.cache)?);
    if let Some(h) = crate::advice::dataset_note(&ds) {
        note!("{h}");
    }
    if !std::io::stdout().is_terminal() {
        anyhow::bail!(
            "stdout is not a terminal, so there is nowhere to draw: use `pcimg render {} -o frame.png` for a file",
            a.view.path.display()
        );
    }
    // The same detection as the inspector's: the terminal (or the tmux server)
    // is asked, at most about a second.
    let mut found = term::detect(a.protocol, term::probe::CAP);
    if let Some(set) = a.symbols {
        found.use_symbols(set);
    }
    found.prepare();
    if let Some(n) = crate::advice::protocol_note(&found.choice) {
        note!("{n}");
    }
    let cam = view::camera_for(&a.view, &ds)?;
    if a.view.print_camera {
        note!("{}", cam.to_json());
    }
    // The size detection read (TIOCGWINSZ), 80×24 should the kernel not say.
    let (term_cols, term_rows) = found
        .winsize
        .filter(|w| w.cols > 0 && w.rows > 0)
        .map_or((80, 24), |w| (w.cols, w.rows));
    let (cols, rows, w, h) = frame_size((term_cols, term_rows), found.cell_pixels, a.cols);
    let printed = view::render_once(ds, &a.view, &cam, w, h).and_then(|(frame, report)| {
        Ok((
            term::print_frame(&crate::pixels(&frame), &found.choice, cols, rows)?,
            report,
        ))
    });
    term::tmux::restore_passthrough();
    let ((), report) = printed?;
    super::print_out(&format!("{}\n", view::describe(&report)))?;
    Ok(())
}

/// The picture in cells and pixels: `want` columns (the terminal's width when
/// not given, never wider, at least 10) by the terminal's rows less three for the
/// report, at `cell` pixels a cell (text: a few pixels a symbol's sub-cell).
fn frame_size(
    (term_cols, term_rows): (u16, u16),
    (cw, ch): (u32, u32),
    want: Option<u16>,
) -> (u16, u16, u32, u32) {
    let cols = want.unwrap_or(term_cols).min(term_cols.max(10)).max(10);
    let rows = term_rows.saturating_sub(3).max(5);
    (cols, rows, cols as u32 * cw, rows as u32 * ch)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_narrow_the_picture_at_the_terminals_cell_size() {
        // 100×40 cells of 10×20 pixels.
        let cell = (10, 20);
        assert_eq!(frame_size((100, 40), cell, None), (100, 37, 1000, 740));
        assert_eq!(frame_size((100, 40), cell, Some(40)), (40, 37, 400, 740));
        // Never wider than the terminal, never narrower than 10 columns.
        assert_eq!(frame_size((100, 40), cell, Some(300)).0, 100);
        assert_eq!(frame_size((100, 40), cell, Some(3)).0, 10);
        assert_eq!(frame_size((100, 40), (1, 2), Some(40)), (40, 37, 40, 74));
    }
}
