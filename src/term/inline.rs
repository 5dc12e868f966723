//! Printing a frame inline in the terminal: sixel through our own encoder
//! ([`super::sixel`], at the frame's exact pixel size), kitty graphics (direct,
//! in-band RGBA, chunked) and iTerm2 (inline PNG) written here, Unicode
//! half-blocks through viuer. Nothing here queries the terminal (a terminal or pty
//! that never answers would hang the command): `auto` must be resolved by the
//! caller from the environment first.

use crate::render::Frame;
use std::io::Write;

/// An inline image protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Chosen from the environment (by the caller, before printing).
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
/// their own pixel size (render them at the terminal's cell size × cells); `Auto`
/// prints half-blocks (resolve it first).
pub fn print_frame(frame: &Frame, protocol: Protocol, cols: u16, rows: u16) -> anyhow::Result<()> {
    let seq = match protocol {
        Protocol::Sixel => {
            let seq = super::sixel::encode(&frame.rgba, frame.width, frame.height)?;
            if std::env::var_os("TMUX").is_some() {
                super::sixel::tmux_passthrough(&seq)
            } else {
                seq
            }
        }
        Protocol::Kitty => kitty_sequence(frame, cols, rows),
        Protocol::Iterm => iterm_sequence(frame, cols, rows)?,
        Protocol::Auto | Protocol::Halfblocks => {
            let img = image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
                .ok_or_else(|| anyhow::anyhow!("frame buffer has the wrong size"))?;
            let conf = viuer::Config {
                width: Some(cols as u32),
                height: Some(rows as u32),
                absolute_offset: false,
                // All off: viuer then draws blocks and asks the terminal nothing.
                use_kitty: false,
                use_sixel: false,
                use_iterm: false,
                truecolor: true,
                ..Default::default()
            };
            viuer::print(&image::DynamicImage::ImageRgba8(img), &conf)
                .map_err(|e| anyhow::anyhow!("cannot print the frame: {e}"))?;
            return Ok(());
        }
    };
    let mut out = std::io::stdout().lock();
    out.write_all(seq.as_bytes())?;
    out.write_all(b"\n")?;
    out.flush()?;
    Ok(())
}

/// The kitty graphics sequence that shows `frame` (RGBA, direct transfer in
/// 4096-byte base64 chunks) over `cols` × `rows` cells.
pub fn kitty_sequence(frame: &Frame, cols: u16, rows: u16) -> String {
    use base64::Engine as _;
    let data = base64::engine::general_purpose::STANDARD.encode(&frame.rgba);
    let chunks: Vec<&[u8]> = data.as_bytes().chunks(4096).collect();
    let mut seq = String::with_capacity(data.len() + chunks.len() * 16 + 64);
    for (i, chunk) in chunks.iter().enumerate() {
        let more = u8::from(i + 1 < chunks.len());
        let chunk = std::str::from_utf8(chunk).unwrap_or_default();
        if i == 0 {
            seq.push_str(&format!(
                "\x1b_Ga=T,f=32,s={},v={},c={cols},r={rows},q=2,m={more};{chunk}\x1b\\",
                frame.width, frame.height
            ));
        } else {
            seq.push_str(&format!("\x1b_Gm={more};{chunk}\x1b\\"));
        }
    }
    seq
}

/// The iTerm2 inline-image sequence that shows `frame` (as PNG) over `cols` ×
/// `rows` cells.
pub fn iterm_sequence(frame: &Frame, cols: u16, rows: u16) -> anyhow::Result<String> {
    use base64::Engine as _;
    let img = image::RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
        .ok_or_else(|| anyhow::anyhow!("frame buffer has the wrong size"))?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)?;
    let png = png.into_inner();
    Ok(format!(
        "\x1b]1337;File=inline=1;size={};width={cols};height={rows};preserveAspectRatio=1:{}\x07",
        png.len(),
        base64::engine::general_purpose::STANDARD.encode(&png)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine as _;

    fn frame(w: u32, h: u32) -> Frame {
        Frame {
            width: w,
            height: h,
            rgba: (0..w * h * 4).map(|i| (i % 251) as u8).collect(),
            stats: Default::default(),
        }
    }

    #[test]
    fn kitty_frames_are_chunked_rgba_that_decodes_back() {
        let f = frame(64, 48); // 12,288 bytes: 16,384 of base64, four chunks
        let seq = kitty_sequence(&f, 20, 10);
        let parts: Vec<&str> = seq.split("\x1b\\").filter(|p| !p.is_empty()).collect();
        assert_eq!(parts.len(), 4);
        assert!(parts[0].starts_with("\x1b_Ga=T,f=32,s=64,v=48,c=20,r=10,q=2,m=1;"));
        assert!(parts[3].starts_with("\x1b_Gm=0;"));
        let data: String = parts.iter().map(|p| p.split_once(';').unwrap().1).collect();
        let back = base64::engine::general_purpose::STANDARD
            .decode(data)
            .unwrap();
        assert_eq!(back, f.rgba);
    }

    #[test]
    fn iterm_frames_are_inline_png() {
        let f = frame(8, 4);
        let seq = iterm_sequence(&f, 4, 2).unwrap();
        let (head, body) = seq.split_once(':').unwrap();
        assert!(
            head.starts_with("\x1b]1337;File=inline=1;size=")
                && head.ends_with("width=4;height=2;preserveAspectRatio=1")
        );
        let png = base64::engine::general_purpose::STANDARD
            .decode(body.trim_end_matches('\x07'))
            .unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgba8();
        assert_eq!(img.into_raw(), f.rgba);
    }
}
