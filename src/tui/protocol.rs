//! The inspector's terminal graphics: which image protocol to use (kitty, sixel,
//! iTerm2 or Unicode half-blocks), the size of a cell in pixels, and encoding a
//! rendered frame for that protocol. Nothing else in the inspector asks the
//! terminal about its capabilities.
//!
//! The choice never queries the terminal through stdin: `--protocol` wins, then
//! environment hints (`KITTY_WINDOW_ID`, `TERM`, `TERM_PROGRAM`); inside tmux the
//! default is half-blocks. (`Picker::from_query_stdio` waits up to 2 s, and in
//! tmux its query thread swallowed a key press and left raw mode: see
//! `docs/notes/terminal-frames.md`.)
//!
//! Encoding runs on the render worker, so the event loop only copies cells; kitty
//! frames all use one image id ([`KITTY_IMAGE_ID`]) so each frame replaces the last
//! in the terminal's memory instead of piling up. Sixel frames come from our own
//! encoder ([`crate::term::sixel`]) and are handed to ratatui-image's `Sixel`
//! ready-made, which draws them as ratatui-image does its own: the escape string in
//! the pane's first cell, the other cells skipped.

use crate::render::Frame;
use crate::term::Protocol as Requested;
use crate::term::sixel;
use ratatui::layout::Size;
use ratatui_image::protocol::Protocol;
use ratatui_image::protocol::halfblocks::Halfblocks;
use ratatui_image::protocol::iterm2::Iterm2;
use ratatui_image::protocol::kitty::Kitty;
use ratatui_image::protocol::sixel::Sixel;

/// The image protocol the inspector draws with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Graphics {
    Kitty,
    Sixel,
    Iterm2,
    Halfblocks,
}

impl Graphics {
    pub fn name(&self) -> &'static str {
        match self {
            Graphics::Kitty => "kitty",
            Graphics::Sixel => "sixel",
            Graphics::Iterm2 => "iTerm2",
            Graphics::Halfblocks => "half-blocks",
        }
    }
}

/// Whether the protocol draws the whole image from the pane's first cell and
/// skips the others (sixel, iTerm2): text drawn over such an image is not
/// replaced by the diff when it goes away, so the screen must be redrawn.
pub fn image_in_one_cell(graphics: Graphics) -> bool {
    matches!(graphics, Graphics::Sixel | Graphics::Iterm2)
}

/// The one kitty image id the inspector uses (frames replace each other).
pub const KITTY_IMAGE_ID: u32 = 0x00_70_63_69; // "pci"

/// The escape sequence that deletes the inspector's kitty image, sent on exit.
pub fn kitty_delete_sequence() -> String {
    format!("\x1b_Ga=d,d=I,i={KITTY_IMAGE_ID},q=2\x1b\\")
}

/// The environment variables the choice looks at.
#[derive(Debug, Clone, Default)]
pub struct TerminalEnv {
    pub term: Option<String>,
    pub term_program: Option<String>,
    pub kitty_window_id: Option<String>,
    pub tmux: Option<String>,
    pub lc_terminal: Option<String>,
}

impl TerminalEnv {
    /// This process's environment.
    pub fn from_process() -> TerminalEnv {
        let var = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        TerminalEnv {
            term: var("TERM"),
            term_program: var("TERM_PROGRAM"),
            kitty_window_id: var("KITTY_WINDOW_ID"),
            tmux: var("TMUX"),
            lc_terminal: var("LC_TERMINAL"),
        }
    }

    /// Whether we run inside tmux (or screen).
    pub fn in_multiplexer(&self) -> bool {
        self.tmux.is_some()
            || self
                .term
                .as_deref()
                .is_some_and(|t| t.starts_with("tmux") || t.starts_with("screen"))
            || self.term_program.as_deref() == Some("tmux")
    }
}

/// Picks the protocol: the user's request, else environment hints, else
/// half-blocks (which every terminal with colour shows).
pub fn choose(requested: Requested, env: &TerminalEnv) -> Graphics {
    match requested {
        Requested::Kitty => return Graphics::Kitty,
        Requested::Sixel => return Graphics::Sixel,
        Requested::Iterm => return Graphics::Iterm2,
        Requested::Halfblocks => return Graphics::Halfblocks,
        Requested::Auto => {}
    }
    if env.in_multiplexer() {
        // tmux passes images through only when configured to; blocks always work.
        return Graphics::Halfblocks;
    }
    let term = env.term.as_deref().unwrap_or("").to_ascii_lowercase();
    let program = env
        .term_program
        .as_deref()
        .unwrap_or("")
        .to_ascii_lowercase();
    if env.kitty_window_id.is_some() || term.contains("kitty") || term.contains("ghostty") {
        return Graphics::Kitty;
    }
    if program == "ghostty" {
        return Graphics::Kitty;
    }
    if program == "iterm.app"
        || program == "wezterm"
        || env.lc_terminal.as_deref() == Some("iTerm2")
    {
        return Graphics::Iterm2;
    }
    if term.contains("foot") || term.contains("mlterm") || term.contains("sixel") {
        return Graphics::Sixel;
    }
    Graphics::Halfblocks
}

/// Pixels per cell: the terminal's own numbers when it reports its size in pixels,
/// else 10×20. Half-blocks are always 1×2.
pub fn cell_pixels(graphics: Graphics) -> (u32, u32) {
    if graphics == Graphics::Halfblocks {
        return (1, 2);
    }
    let (cols, rows) = crossterm::terminal::size().unwrap_or((0, 0));
    crossterm::terminal::window_size()
        .ok()
        .filter(|w| w.width > 0 && w.height > 0 && cols > 0 && rows > 0)
        .map(|w| (w.width as u32 / cols as u32, w.height as u32 / rows as u32))
        .filter(|&(w, h)| w > 0 && h > 0)
        .unwrap_or((10, 20))
}

/// The sixel escape string for a pane of `cells`: the pane's cells erased first
/// (ECH per row, as ratatui-image does, so no old text shows through), then the
/// image; inside tmux all of it goes through passthrough.
fn sixel_for_pane(frame: &Frame, cells: (u16, u16), in_tmux: bool) -> anyhow::Result<String> {
    let image = sixel::encode(&frame.rgba, frame.width, frame.height)?;
    let (w, h) = cells;
    let mut s = String::with_capacity(image.len() + 16 * h as usize);
    if h <= 1 {
        s.push_str(&format!("\x1b[{w}X"));
    } else {
        for _ in 0..h {
            s.push_str(&format!("\x1b[{w}X\x1b[1B"));
        }
        s.push_str(&format!("\x1b[{h}A"));
    }
    s.push_str(&image);
    Ok(if in_tmux {
        sixel::tmux_passthrough(&s)
    } else {
        s
    })
}

/// Encodes `frame` (rendered at `cells` × the cell size in pixels) for `graphics`.
pub fn encode(
    graphics: Graphics,
    frame: &Frame,
    cells: (u16, u16),
    in_tmux: bool,
) -> anyhow::Result<Protocol> {
    let size = Size::new(cells.0, cells.1);
    let err = |e: ratatui_image::errors::Errors| anyhow::anyhow!("cannot encode the frame: {e}");
    let image = || {
        image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
            .map(image::DynamicImage::ImageRgba8)
            .ok_or_else(|| anyhow::anyhow!("frame buffer has the wrong size"))
    };
    Ok(match graphics {
        Graphics::Halfblocks => Protocol::Halfblocks(Halfblocks::new(image()?, size).map_err(err)?),
        Graphics::Sixel => Protocol::Sixel(Sixel {
            data: sixel_for_pane(frame, cells, in_tmux)?,
            size,
            is_tmux: in_tmux,
        }),
        // zlib-compressed: a tenth of the bytes for ~5 ms more (notes/terminal-frames.md).
        Graphics::Kitty => {
            Protocol::Kitty(Kitty::new(image()?, size, KITTY_IMAGE_ID, in_tmux, true).map_err(err)?)
        }
        Graphics::Iterm2 => Protocol::ITerm2(Iterm2::new(image()?, size, in_tmux).map_err(err)?),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(term: &str, program: &str) -> TerminalEnv {
        TerminalEnv {
            term: Some(term.into()),
            term_program: (!program.is_empty()).then(|| program.into()),
            ..Default::default()
        }
    }

    #[test]
    fn the_flag_wins_then_hints_then_half_blocks() {
        let kitty = TerminalEnv {
            kitty_window_id: Some("1".into()),
            ..env("xterm-kitty", "")
        };
        assert_eq!(choose(Requested::Sixel, &kitty), Graphics::Sixel);
        assert_eq!(choose(Requested::Auto, &kitty), Graphics::Kitty);
        assert_eq!(
            choose(Requested::Auto, &env("xterm-256color", "iTerm.app")),
            Graphics::Iterm2
        );
        assert_eq!(choose(Requested::Auto, &env("foot", "")), Graphics::Sixel);
        assert_eq!(
            choose(Requested::Auto, &env("xterm-256color", "")),
            Graphics::Halfblocks
        );
        let tmux = TerminalEnv {
            tmux: Some("/tmp/tmux-0/default,1,0".into()),
            kitty_window_id: Some("1".into()),
            ..env("tmux-256color", "tmux")
        };
        assert_eq!(choose(Requested::Auto, &tmux), Graphics::Halfblocks);
        assert_eq!(choose(Requested::Kitty, &tmux), Graphics::Kitty);
    }

    #[test]
    fn frames_encode_for_every_protocol() {
        let frame = Frame::background(40, 20, [10, 200, 30]);
        for g in [
            Graphics::Halfblocks,
            Graphics::Sixel,
            Graphics::Kitty,
            Graphics::Iterm2,
        ] {
            let cells = if g == Graphics::Halfblocks {
                (40, 10)
            } else {
                (4, 1)
            };
            let p = encode(g, &frame, cells, false).unwrap();
            assert_eq!(p.size(), Size::new(cells.0, cells.1), "{}", g.name());
        }
    }
}
