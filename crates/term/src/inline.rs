//! Printing a frame inline in the terminal (`pcimg preview`): sixel through our
//! own encoder ([`super::sixel`], at the frame's exact pixel size), kitty graphics
//! ([`super::kitty`]) and iTerm2 (inline PNG) scaled by the terminal to the cells,
//! text: symbols in colour ([`super::symbols`]). Nothing here queries the terminal: the
//! protocol comes from [`super::detect()`].

use crate::Rgba;
use std::io::Write;

/// An inline image protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Detected: the terminal is asked ([`super::detect()`]).
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
            "text" | "halfblocks" | "blocks" => Ok(Protocol::Halfblocks),
            o => Err(format!(
                "unknown protocol '{o}' (auto, kitty, sixel, iterm, text)"
            )),
        }
    }
}

/// Prints `frame` at the cursor over `cols` × `rows` cells as `choice` says:
/// sixel at the frame's own pixel size (render it at the cell size × cells), kitty
/// and iTerm2 scaled by the terminal to the cells (through tmux: kitty as Unicode
/// placeholders, passed through), else text in the choice's symbols and colours.
pub fn print_frame(
    frame: &Rgba<'_>,
    choice: &super::detect::Choice,
    cols: u16,
    rows: u16,
) -> anyhow::Result<()> {
    use super::Graphics;
    let wrap = |s: String| {
        if choice.passthrough {
            super::tmux::passthrough(&s)
        } else {
            s
        }
    };
    let seq = match choice.graphics {
        Graphics::Sixel => wrap(super::sixel::encode(frame.rgba, frame.width, frame.height)?),
        Graphics::Kitty => kitty_cells(frame, choice, cols, rows),
        Graphics::Iterm2 => wrap(iterm_sequence(frame, cols, rows, false)?),
        Graphics::Halfblocks => {
            let t = &choice.text;
            let text =
                super::symbols::Symbols::of_depth(frame, cols, rows, t.set, t.depth).ansi(t.depth);
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())?;
            out.flush()?;
            return Ok(());
        }
    };
    let mut out = std::io::stdout().lock();
    out.write_all(seq.as_bytes())?;
    out.write_all(b"\n")?;
    out.flush()?;
    Ok(())
}

/// The image id `preview` uses (a fresh one per process would pile up images;
/// one id means the newest preview replaces the older in the terminal's memory).
const PREVIEW_IMAGE_ID: u32 = 0x00_70_63_70;

/// A kitty frame over `cols` × `rows` cells at the cursor: room made first (so
/// scrolling happens before the image is placed), then the image, then the
/// cursor below it. Through tmux the image is a virtual placement and the cells
/// are written as Unicode placeholders in the image id's colour.
fn kitty_cells(frame: &Rgba<'_>, choice: &super::detect::Choice, cols: u16, rows: u16) -> String {
    let p = super::kitty::Placement {
        id: PREVIEW_IMAGE_ID,
        cols,
        rows,
        placeholders: choice.placeholders,
        passthrough: choice.passthrough,
        below_text: false,
    };
    let mut s = "\n".repeat(rows as usize);
    s.push_str(&format!("\x1b[{rows}A\r"));
    s.push_str(&super::kitty::transmit(frame, p));
    if choice.placeholders {
        let (r, g, b) = super::kitty::id_color(PREVIEW_IMAGE_ID);
        for row in 0..rows.min(super::kitty::max_cells()) {
            s.push_str(&format!("\x1b[38;2;{r};{g};{b}m"));
            for col in 0..cols.min(super::kitty::max_cells()) {
                s.push_str(&super::kitty::placeholder(row, col, PREVIEW_IMAGE_ID));
            }
            s.push_str("\x1b[39m\r\n");
        }
        s.push_str("\x1b[1A");
    } else {
        s.push_str(&format!("\x1b[{}B", rows.saturating_sub(1)));
    }
    s
}

/// The iTerm2 inline-image sequence that shows `frame` (as PNG) over `cols` ×
/// `rows` cells; with `keep_cursor` the cursor stays where it was.
pub fn iterm_sequence(
    frame: &Rgba<'_>,
    cols: u16,
    rows: u16,
    keep_cursor: bool,
) -> anyhow::Result<String> {
    use base64::Engine as _;
    use image::ImageEncoder as _;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    if frame.rgba.len() != frame.width as usize * frame.height as usize * 4 {
        anyhow::bail!("frame buffer has the wrong size");
    }
    // RGB with the adaptive filter at the default level: frames are about a
    // third smaller than image's fast RGBA PNG for ~5 ms more (bench/RESULTS.md).
    let rgb: Vec<u8> = frame
        .rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    let mut png = Vec::new();
    PngEncoder::new_with_quality(&mut png, CompressionType::Default, FilterType::Adaptive)
        .write_image(
            &rgb,
            frame.width,
            frame.height,
            image::ExtendedColorType::Rgb8,
        )?;
    Ok(format!(
        "\x1b]1337;File=inline=1;size={};width={cols};height={rows};preserveAspectRatio=0{}:{}\x07",
        png.len(),
        if keep_cursor {
            ";doNotMoveCursor=1"
        } else {
            ""
        },
        base64::engine::general_purpose::STANDARD.encode(&png)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine as _;

    use crate::test_frame as frame;

    #[test]
    fn iterm_frames_are_inline_png() {
        let f = frame(8, 4);
        let seq = iterm_sequence(&f, 4, 2, true).unwrap();
        let (head, body) = seq.split_once(':').unwrap();
        assert!(
            head.starts_with("\x1b]1337;File=inline=1;size=")
                && head.ends_with("width=4;height=2;preserveAspectRatio=0;doNotMoveCursor=1")
        );
        let png = base64::engine::general_purpose::STANDARD
            .decode(body.trim_end_matches('\x07'))
            .unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        let rgb: Vec<u8> = f.rgba.chunks(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
        assert_eq!(img.into_raw(), rgb);
    }
}
