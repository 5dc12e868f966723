//! Printing a frame inline in the terminal through viuer: kitty graphics (direct,
//! in-band transfer only), sixel (icy_sixel, no C libraries), iTerm2, or Unicode
//! half-blocks where the terminal shows no images (tmux without passthrough, plain
//! xterm).

use crate::render::Frame;

/// An inline image protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Detect from the environment (viuer's probes).
    Auto,
    Kitty,
    Sixel,
    Iterm,
    Halfblocks,
}

impl std::str::FromStr for Protocol {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Protocol::Auto),
            "kitty" => Ok(Protocol::Kitty),
            "sixel" => Ok(Protocol::Sixel),
            "iterm" | "iterm2" => Ok(Protocol::Iterm),
            "halfblocks" | "blocks" => Ok(Protocol::Halfblocks),
            o => Err(format!(
                "unknown protocol '{o}' (auto, kitty, sixel, iterm, halfblocks)"
            )),
        }
    }
}

/// The terminal's size in cells and, when it reports it, in pixels.
pub fn terminal_pixels() -> (u16, u16, Option<(u32, u32)>) {
    let (cols, rows) = crossterm::terminal::size().unwrap_or((80, 24));
    let px = crossterm::terminal::window_size()
        .ok()
        .filter(|w| w.width > 0 && w.height > 0)
        .map(|w| (w.width as u32, w.height as u32));
    (cols, rows, px)
}

/// Prints `frame` at the cursor, `cols` × `rows` cells.
pub fn print_frame(frame: &Frame, protocol: Protocol, cols: u16, rows: u16) -> anyhow::Result<()> {
    let img = image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
        .ok_or_else(|| anyhow::anyhow!("frame buffer has the wrong size"))?;
    let img = image::DynamicImage::ImageRgba8(img);
    let (kitty, sixel, iterm) = match protocol {
        Protocol::Auto => (true, true, true),
        Protocol::Kitty => (true, false, false),
        Protocol::Sixel => (false, true, false),
        Protocol::Iterm => (false, false, true),
        Protocol::Halfblocks => (false, false, false),
    };
    let conf = viuer::Config {
        width: Some(cols as u32),
        height: Some(rows as u32),
        absolute_offset: false,
        use_kitty: kitty,
        use_sixel: sixel,
        use_iterm: iterm,
        truecolor: true,
        ..Default::default()
    };
    viuer::print(&img, &conf).map_err(|e| anyhow::anyhow!("cannot print the frame: {e}"))?;
    Ok(())
}
