//! Printing a frame inline in the terminal: sixel through our own encoder
//! ([`super::sixel`], at the frame's exact pixel size), kitty graphics (direct,
//! in-band transfer only), iTerm2 or Unicode half-blocks through viuer, which also
//! detects what the terminal shows when the protocol is `auto`.

use crate::render::Frame;
use std::io::Write;

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

/// Prints `frame` at the cursor, `cols` × `rows` cells. Sixel frames are sent at
/// their own pixel size (render them at the terminal's cell size × cells).
pub fn print_frame(frame: &Frame, protocol: Protocol, cols: u16, rows: u16) -> anyhow::Result<()> {
    // viuer asks for sixel first too (a DA1 query) when the protocol is auto.
    if protocol == Protocol::Sixel || (protocol == Protocol::Auto && viuer::is_sixel_supported()) {
        let mut seq = super::sixel::encode(&frame.rgba, frame.width, frame.height)?;
        if std::env::var_os("TMUX").is_some() {
            seq = super::sixel::tmux_passthrough(&seq);
        }
        let mut out = std::io::stdout().lock();
        out.write_all(seq.as_bytes())?;
        out.write_all(b"\n")?;
        out.flush()?;
        return Ok(());
    }
    let img = image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
        .ok_or_else(|| anyhow::anyhow!("frame buffer has the wrong size"))?;
    let img = image::DynamicImage::ImageRgba8(img);
    let (kitty, iterm) = match protocol {
        Protocol::Auto => (true, true),
        Protocol::Kitty => (true, false),
        Protocol::Iterm => (false, true),
        Protocol::Sixel | Protocol::Halfblocks => (false, false),
    };
    let conf = viuer::Config {
        width: Some(cols as u32),
        height: Some(rows as u32),
        absolute_offset: false,
        use_kitty: kitty,
        use_sixel: false,
        use_iterm: iterm,
        truecolor: true,
        ..Default::default()
    };
    viuer::print(&img, &conf).map_err(|e| anyhow::anyhow!("cannot print the frame: {e}"))?;
    Ok(())
}
