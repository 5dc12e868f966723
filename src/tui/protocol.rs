//! The inspector's terminal graphics: encoding a rendered frame for the protocol
//! detection chose ([`crate::term::detect()`]), as a [`PaneImage`] the event loop
//! only copies into ratatui's buffer.
//!
//! Encoding runs on the render worker. Kitty frames all use one image id
//! ([`KITTY_IMAGE_ID`]) so each frame replaces the last in the terminal's memory
//! (sending an image under an id in use deletes the old one and its placements),
//! and are shown by Unicode placeholder cells (which tmux keeps like text), scaled
//! by the terminal to the pane whatever their pixel size: frames rendered at
//! reduced resolution while the camera moves cost a quarter of the bytes. Where
//! the terminal has no placeholders (kitty before 0.28), a kitty frame is placed
//! directly at the pane's first cell instead, like sixel and iTerm2 frames: one
//! escape string in the pane's first cell, the other cells skipped; sixel comes
//! from our own encoder ([`crate::term::sixel`]).

use crate::render::Frame;
use crate::term::symbols::{Depth, Symbols, TextStyle};
use crate::term::{kitty, sixel};
use ratatui::buffer::{Buffer, CellDiffOption};
use ratatui::layout::Rect;
use ratatui::style::Color;
use ratatui::widgets::Widget;

pub use crate::term::Graphics;

/// How frames are encoded: the protocol and how it reaches the terminal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Encoding {
    pub graphics: Graphics,
    /// Wrapped in tmux passthrough.
    pub passthrough: bool,
    /// Kitty frames shown by Unicode placeholder cells; else placed directly at
    /// the pane's first cell (kitty before 0.28 has no placeholders).
    pub placeholders: bool,
    /// Text frames: the symbols and colours.
    pub text: (crate::term::symbols::SymbolSet, Depth),
    /// The overlays (scale bar, crosshair, picks) are drawn into the frame's
    /// pixels, not as cells over it: a cell written over the image would take
    /// it away (tmux drawing sixel itself, `Choice::text_erases_images`).
    pub overlays_in_pixels: bool,
}

impl Encoding {
    pub fn new(graphics: Graphics) -> Encoding {
        Encoding {
            graphics,
            passthrough: false,
            placeholders: true,
            overlays_in_pixels: false,
            text: {
                let t = TextStyle::default();
                (t.set, t.depth)
            },
        }
    }
}

/// Whether the protocol draws the whole image from the pane's first cell and
/// skips the others (sixel, iTerm2, kitty placed directly): text drawn over such
/// an image is not replaced by the diff when it goes away, so the screen must be
/// redrawn.
pub fn image_in_one_cell(enc: Encoding) -> bool {
    match enc.graphics {
        Graphics::Sixel | Graphics::Iterm2 => true,
        Graphics::Kitty => !enc.placeholders,
        Graphics::Halfblocks => false,
    }
}

/// Whether the image shows through text drawn over its cells until it is
/// deleted (kitty placed directly: drawn below text, but above cells of the
/// default background, as the help's are): it must be taken off before the
/// help is drawn there. The view's overlays are text over it by design.
pub fn image_above_text(enc: Encoding) -> bool {
    enc.graphics == Graphics::Kitty && !enc.placeholders
}

/// The one kitty image id the inspector uses (frames replace each other).
pub const KITTY_IMAGE_ID: u32 = 0x00_70_63_69; // "pci"

/// A frame encoded for the view pane.
pub enum PaneImage {
    /// One escape string drawn from the pane's first cell, the others skipped
    /// (sixel, iTerm2, and kitty placed directly).
    FirstCell { data: String, cells: (u16, u16) },
    /// A kitty image sent with the first cell, shown by placeholder cells.
    Kitty { transmit: String, cells: (u16, u16) },
    /// Text: a symbol and two colours a cell.
    Text(Symbols, Depth),
}

impl PaneImage {
    /// The pane's size in cells that the image covers.
    pub fn cells(&self) -> (u16, u16) {
        match self {
            PaneImage::FirstCell { cells, .. } | PaneImage::Kitty { cells, .. } => *cells,
            PaneImage::Text(t, _) => (t.cols, t.rows),
        }
    }

    /// Bytes of escape sequences the image costs (text: cells × ~20).
    pub fn bytes(&self) -> usize {
        match self {
            PaneImage::FirstCell { data, .. } => data.len(),
            PaneImage::Kitty { transmit, cells } => {
                transmit.len() + cells.0 as usize * cells.1 as usize * 4
            }
            PaneImage::Text(t, _) => t.cells.len() * 20,
        }
    }
}

/// A colour as ratatui writes it at the terminal's depth: 24-bit, an index of
/// the 256 palette, or one of the 16 named colours (SGR 30–37, 90–97).
fn colour(c: [u8; 3], depth: Depth) -> Color {
    use crate::term::symbols::{ansi16, palette256};
    match depth {
        Depth::True => Color::Rgb(c[0], c[1], c[2]),
        Depth::C256 => Color::Indexed(palette256(c)),
        Depth::C16 => [
            Color::Black,
            Color::Red,
            Color::Green,
            Color::Yellow,
            Color::Blue,
            Color::Magenta,
            Color::Cyan,
            Color::Gray,
            Color::DarkGray,
            Color::LightRed,
            Color::LightGreen,
            Color::LightYellow,
            Color::LightBlue,
            Color::LightMagenta,
            Color::LightCyan,
            Color::White,
        ][ansi16(c) as usize],
    }
}

/// A width of one, whatever the symbol's characters would measure.
const UNIT_WIDTH: CellDiffOption =
    CellDiffOption::ForcedWidth(std::num::NonZeroU16::new(1).unwrap());

impl Widget for &PaneImage {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let (w, h) = self.cells();
        let area = Rect::new(area.x, area.y, area.width.min(w), area.height.min(h));
        if area.is_empty() {
            return;
        }
        match self {
            PaneImage::Text(t, depth) => {
                for y in 0..area.height {
                    for (x, c) in t.row(y).iter().take(area.width as usize).enumerate() {
                        if let Some(cell) = buf.cell_mut((area.x + x as u16, area.y + y)) {
                            cell.set_char(c.symbol)
                                .set_fg(colour(c.fg, *depth))
                                .set_bg(colour(c.bg, *depth));
                        }
                    }
                }
            }
            PaneImage::FirstCell { data, .. } => {
                for y in area.top()..area.bottom() {
                    for x in area.left()..area.right() {
                        if let Some(cell) = buf.cell_mut((x, y)) {
                            if (x, y) == (area.x, area.y) {
                                cell.set_symbol(data).set_diff_option(UNIT_WIDTH);
                            } else {
                                cell.set_diff_option(CellDiffOption::Skip);
                            }
                        }
                    }
                }
            }
            PaneImage::Kitty { transmit, .. } => {
                let (r, g, b) = kitty::id_color(KITTY_IMAGE_ID);
                let max = kitty::max_cells();
                for y in area.top()..area.bottom().min(area.y + max) {
                    for x in area.left()..area.right().min(area.x + max) {
                        let Some(cell) = buf.cell_mut((x, y)) else {
                            continue;
                        };
                        let mut symbol = String::new();
                        if (x, y) == (area.x, area.y) {
                            symbol.push_str(transmit);
                        }
                        symbol.push_str(&kitty::placeholder(
                            y - area.y,
                            x - area.x,
                            KITTY_IMAGE_ID,
                        ));
                        cell.set_symbol(&symbol)
                            .set_fg(Color::Rgb(r, g, b))
                            .set_diff_option(UNIT_WIDTH);
                    }
                }
            }
        }
    }
}

/// The escape sequence that deletes the inspector's kitty image, sent on exit.
pub fn kitty_delete_sequence(passthrough: bool) -> String {
    kitty::delete(KITTY_IMAGE_ID, passthrough)
}

/// The cells of a pane erased (ECH per row, so no old text shows through), the
/// cursor back at its first cell.
fn erase_pane(s: &mut String, (w, h): (u16, u16)) {
    if h <= 1 {
        s.push_str(&format!("\x1b[{w}X"));
    } else {
        for _ in 0..h {
            s.push_str(&format!("\x1b[{w}X\x1b[1B"));
        }
        s.push_str(&format!("\x1b[{h}A"));
    }
}

/// The sixel escape string for a pane of `cells` (`full` pixels): the pane
/// erased, then the image. Sixel cannot be scaled by the terminal: a smaller
/// (moving) frame is enlarged here and sent in fewer colours.
fn sixel_for_pane(
    frame: &Frame,
    cells: (u16, u16),
    passthrough: bool,
    full: (u32, u32),
    colors: usize,
) -> anyhow::Result<String> {
    let image = if (frame.width, frame.height) == full || frame.width == 0 || frame.height == 0 {
        sixel::encode_colors(&frame.rgba, frame.width, frame.height, colors)?
    } else {
        let big = enlarge(frame, full);
        sixel::encode_colors(&big, full.0, full.1, sixel::MOVING_COLORS)?
    };
    let mut s = String::with_capacity(image.len() + 16 * cells.1 as usize);
    erase_pane(&mut s, cells);
    s.push_str(&image);
    Ok(if passthrough {
        crate::term::tmux::passthrough(&s)
    } else {
        s
    })
}

/// `frame` enlarged to `full` pixels by repeating pixels.
fn enlarge(frame: &Frame, (w, h): (u32, u32)) -> Vec<u8> {
    let mut out = Vec::with_capacity(w as usize * h as usize * 4);
    for y in 0..h {
        let sy = (y as u64 * frame.height as u64 / h as u64) as usize;
        let row = &frame.rgba[sy * frame.width as usize * 4..][..frame.width as usize * 4];
        for x in 0..w {
            let sx = (x as u64 * frame.width as u64 / w as u64) as usize * 4;
            out.extend_from_slice(&row[sx..sx + 4]);
        }
    }
    out
}

/// The iTerm2 escape string for a pane of `cells`: the pane erased, then the frame
/// as PNG stretched over the pane by the terminal, the cursor left where it was.
fn iterm_for_pane(frame: &Frame, cells: (u16, u16), passthrough: bool) -> anyhow::Result<String> {
    let mut s = String::new();
    erase_pane(&mut s, cells);
    s.push_str(&crate::term::inline::iterm_sequence(
        &crate::pixels(frame),
        cells.0,
        cells.1,
        true,
    )?);
    Ok(if passthrough {
        crate::term::tmux::passthrough(&s)
    } else {
        s
    })
}

/// The escape string that draws the picture under cells `x..x + n` of row `y`
/// (from the pane's top-left) again, as a small image at the run's first cell:
/// for sixel and iTerm2, whose pixels under overlay cells that went away are
/// gone, at a few hundred bytes rather than the whole frame's. `frame` is the
/// frame shown over a pane of `cells` cells of `cell_pixels` pixels (a reduced
/// frame is enlarged as the whole one was). `None` for the other protocols, a
/// run outside the pane, an empty frame, and through tmux: tmux passes an
/// escape string through at the outer terminal's cursor, which it moves only
/// when it writes cells, so a patch would land wherever that was (the whole
/// image is sent again instead, from the pane's first cell as every frame).
pub fn patch(
    enc: Encoding,
    frame: &Frame,
    cells: (u16, u16),
    cell_pixels: (u32, u32),
    (x, y, n): (u16, u16, u16),
) -> Option<String> {
    let (cw, ch) = (cell_pixels.0.max(1), cell_pixels.1.max(1));
    let fits = n > 0 && x as u32 + n as u32 <= cells.0 as u32 && y < cells.1;
    if !fits || frame.width == 0 || frame.height == 0 || enc.passthrough {
        return None;
    }
    let (w, h) = (n as u32 * cw, ch);
    // Pixels of the pane as the whole image showed them, sampled from the frame.
    let (pane_w, pane_h) = (cells.0 as u64 * cw as u64, cells.1 as u64 * ch as u64);
    let mut rgba = Vec::with_capacity(w as usize * h as usize * 4);
    for py in 0..h {
        let sy = ((y as u64 * ch as u64 + py as u64) * frame.height as u64 / pane_h) as usize;
        for px in 0..w {
            let sx = ((x as u64 * cw as u64 + px as u64) * frame.width as u64 / pane_w) as usize;
            let i = (sy * frame.width as usize + sx) * 4;
            rgba.extend_from_slice(frame.rgba.get(i..i + 4)?);
        }
    }
    let image = match enc.graphics {
        Graphics::Sixel => sixel::encode(&rgba, w, h).ok()?,
        Graphics::Iterm2 => crate::term::inline::iterm_sequence(
            &crate::term::Rgba {
                width: w,
                height: h,
                rgba: &rgba,
            },
            n,
            1,
            true,
        )
        .ok()?,
        Graphics::Kitty | Graphics::Halfblocks => return None,
    };
    Some(image)
}

/// Encodes `frame` for a pane of `cells` that is `full` pixels. Kitty and iTerm2
/// frames may be smaller (the terminal scales them); sixel ones are enlarged here.
pub fn encode(
    enc: Encoding,
    frame: &Frame,
    cells: (u16, u16),
    full: (u32, u32),
) -> anyhow::Result<PaneImage> {
    Ok(match enc.graphics {
        Graphics::Halfblocks => PaneImage::Text(
            Symbols::of_depth(
                &crate::pixels(frame),
                cells.0,
                cells.1,
                enc.text.0,
                enc.text.1,
            ),
            enc.text.1,
        ),
        Graphics::Sixel => PaneImage::FirstCell {
            data: sixel_for_pane(frame, cells, enc.passthrough, full, sixel::COLORS)?,
            cells,
        },
        Graphics::Kitty => kitty_for_pane(enc, frame, cells, None),
        Graphics::Iterm2 => PaneImage::FirstCell {
            data: iterm_for_pane(frame, cells, enc.passthrough)?,
            cells,
        },
    })
}

/// Colours a full frame may be reduced to for a slow link, tried in this
/// order until it fits: sixel frames are sent in [`sixel::COLORS`] (32)
/// otherwise, kitty frames exact (deflated RGB). Fewer than 8 turns a
/// coloured scan into a few flat patches.
pub const SLOW_COLORS: [usize; 3] = [32, 16, 8];

/// [`encode`], but a full-resolution sixel or kitty frame that would cost
/// more than `allowance` bytes (the link is slow: `allowance` is what the
/// link carries within the time allowed) is sent in fewer colours
/// ([`SLOW_COLORS`], the first that fits, else the fewest): sixel in fewer
/// palette colours, kitty as an indexed PNG. Returns the image and, when
/// reduced, its colours. Without an allowance (a fast or unmeasured link),
/// for reduced (moving) frames, text and iTerm2, exactly [`encode`].
///
/// `start`: the caller knows the exact frame did not fit last time; the exact
/// encoding is skipped and colours are tried from `start` down (each try is a
/// whole encoding: on a slow link every millisecond before sending counts).
pub fn encode_within(
    enc: Encoding,
    frame: &Frame,
    cells: (u16, u16),
    full: (u32, u32),
    allowance: Option<usize>,
    start: Option<usize>,
) -> anyhow::Result<(PaneImage, Option<usize>)> {
    let full_size = (frame.width, frame.height) == full && frame.width > 0 && frame.height > 0;
    let reducible = matches!(enc.graphics, Graphics::Sixel | Graphics::Kitty);
    let Some(allowance) = allowance.filter(|_| full_size && reducible) else {
        return Ok((encode(enc, frame, cells, full)?, None));
    };
    let exact = match start {
        Some(_) => None,
        None => {
            let exact = encode(enc, frame, cells, full)?;
            if exact.bytes() <= allowance {
                return Ok((exact, None));
            }
            Some(exact)
        }
    };
    let top = start.unwrap_or(usize::MAX);
    let mut cheaper = None;
    for colors in SLOW_COLORS {
        // Sixel frames are already in 32 colours.
        if colors > top || (enc.graphics == Graphics::Sixel && colors >= sixel::COLORS) {
            continue;
        }
        let image = match enc.graphics {
            Graphics::Sixel => PaneImage::FirstCell {
                data: sixel_for_pane(frame, cells, enc.passthrough, full, colors)?,
                cells,
            },
            _ => kitty_for_pane(enc, frame, cells, Some(colors)),
        };
        let fits = image.bytes() <= allowance;
        cheaper = Some((image, Some(colors)));
        if fits {
            break;
        }
    }
    match (cheaper, exact) {
        (Some(c), _) => Ok(c),
        (None, Some(exact)) => Ok((exact, None)),
        (None, None) => Ok((encode(enc, frame, cells, full)?, None)),
    }
}

/// A kitty frame for a pane of `cells`: exact (deflated RGB), or in at most
/// `colors` colours as an indexed PNG.
fn kitty_for_pane(
    enc: Encoding,
    frame: &Frame,
    cells: (u16, u16),
    colors: Option<usize>,
) -> PaneImage {
    let placement = kitty::Placement {
        id: KITTY_IMAGE_ID,
        cols: cells.0,
        rows: cells.1,
        placeholders: enc.placeholders,
        passthrough: enc.passthrough,
        // Placed directly: under the overlays' text.
        below_text: true,
    };
    let transmit = match colors {
        None => kitty::transmit(&crate::pixels(frame), placement),
        Some(c) => kitty::transmit_indexed(&crate::pixels(frame), c, placement),
    };
    if enc.placeholders {
        PaneImage::Kitty { transmit, cells }
    } else {
        // Placed at the cursor, which the draw puts on the pane's first
        // cell, and left there (`C=1`); it replaces the previous frame.
        // Below text: the pane is erased first, as for sixel, so no
        // text left there (the first frame's note, overlays) shows.
        let mut data = String::with_capacity(transmit.len() + 16 * cells.1 as usize);
        erase_pane(&mut data, cells);
        data.push_str(&transmit);
        PaneImage::FirstCell { data, cells }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
            let p = encode(Encoding::new(g), &frame, cells, (40, 20)).unwrap();
            assert_eq!(p.cells(), cells, "{}", g.name());
            assert!(p.bytes() > 0);
        }
    }

    #[test]
    fn reduced_sixel_frames_are_enlarged_to_the_pane_in_fewer_colours() {
        // A 30×30 frame of 40 greys for a pane of 60×60 pixels.
        let mut frame = Frame::background(30, 30, [0, 0, 0]);
        for (i, px) in frame.rgba.chunks_mut(4).enumerate() {
            let v = (i % 40 * 6) as u8;
            px[..3].copy_from_slice(&[v, v, v]);
        }
        let img = encode(Encoding::new(Graphics::Sixel), &frame, (6, 3), (60, 60)).unwrap();
        let PaneImage::FirstCell { data, .. } = img else {
            panic!("sixel is drawn from the first cell");
        };
        assert!(data.contains("\"1;1;60;60#"), "enlarged to the pane");
        let defined = (0..64)
            .filter(|c| data.contains(&format!("#{c};2;")))
            .count();
        assert!(
            (2..=sixel::MOVING_COLORS).contains(&defined),
            "{defined} colours"
        );
        // At full size, the full palette.
        let full = Frame {
            width: 60,
            height: 60,
            rgba: enlarge(&frame, (60, 60)),
            stats: Default::default(),
        };
        let PaneImage::FirstCell { data, .. } =
            encode(Encoding::new(Graphics::Sixel), &full, (6, 3), (60, 60)).unwrap()
        else {
            panic!("sixel is drawn from the first cell");
        };
        let defined = (0..64)
            .filter(|c| data.contains(&format!("#{c};2;")))
            .count();
        assert!(defined > sixel::MOVING_COLORS, "{defined} colours");
    }

    /// A 1200×800 frame of many colours in bands and noise (bytes like a scan's).
    fn busy_frame(w: u32, h: u32) -> Frame {
        let mut frame = Frame::background(w, h, [0, 0, 0]);
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        for (i, px) in frame.rgba.chunks_mut(4).enumerate() {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let (x, y) = ((i as u32 % w) as u64, (i as u32 / w) as u64);
            let n = (seed % 24) as u8;
            px[..3].copy_from_slice(&[
                ((x * 255 / w as u64) as u8).saturating_add(n),
                ((y * 255 / h as u64) as u8).saturating_add(n),
                (((x + y) % 97) as u8).saturating_add(n),
            ]);
        }
        frame
    }

    fn colours_defined(data: &str) -> usize {
        (0..256)
            .filter(|c| data.contains(&format!("#{c};2;")))
            .count()
    }

    #[test]
    fn a_fast_or_unmeasured_link_gets_the_exact_frame() {
        let frame = busy_frame(120, 80);
        for g in [Graphics::Sixel, Graphics::Kitty, Graphics::Halfblocks] {
            let enc = Encoding::new(g);
            let cells = if g == Graphics::Halfblocks {
                (120, 40)
            } else {
                (12, 4)
            };
            let exact = encode(enc, &frame, cells, (120, 80)).unwrap();
            for allowance in [None, Some(exact.bytes()), Some(usize::MAX)] {
                let (image, colors) =
                    encode_within(enc, &frame, cells, (120, 80), allowance, None).unwrap();
                assert_eq!(colors, None, "{} {allowance:?}", g.name());
                assert_eq!(image.bytes(), exact.bytes(), "{}", g.name());
            }
        }
        // Moving (reduced) frames are left as they are, however slow the link.
        let small = busy_frame(60, 40);
        let (_, colors) = encode_within(
            Encoding::new(Graphics::Sixel),
            &small,
            (12, 4),
            (120, 80),
            Some(10),
            None,
        )
        .unwrap();
        assert_eq!(colors, None);
    }

    #[test]
    fn a_slow_link_gets_the_full_frame_in_fewer_colours_that_fit() {
        let frame = busy_frame(240, 160);
        let sixel = Encoding::new(Graphics::Sixel);
        let exact = encode(sixel, &frame, (24, 8), (240, 160)).unwrap();
        let PaneImage::FirstCell { data, .. } = &exact else {
            panic!("sixel is drawn from the first cell");
        };
        assert_eq!(colours_defined(data), sixel::COLORS);
        // A little under the exact frame's bytes: 16 colours fit.
        let (image, colors) = encode_within(
            sixel,
            &frame,
            (24, 8),
            (240, 160),
            Some(exact.bytes() - 1),
            None,
        )
        .unwrap();
        assert_eq!(colors, Some(16));
        let PaneImage::FirstCell { data, .. } = &image else {
            panic!("sixel is drawn from the first cell");
        };
        assert_eq!(colours_defined(data), 16);
        assert!(data.contains("\"1;1;240;160#"), "full resolution");
        assert!(image.bytes() < exact.bytes());
        // Nothing fits: the fewest colours.
        let (image, colors) =
            encode_within(sixel, &frame, (24, 8), (240, 160), Some(100), None).unwrap();
        assert_eq!(colors, Some(8));
        let PaneImage::FirstCell { data, .. } = &image else {
            panic!("sixel is drawn from the first cell");
        };
        assert_eq!(colours_defined(data), 8);

        // Kitty: an indexed PNG of the frame's size, in 32 colours when that fits.
        let kitty = Encoding::new(Graphics::Kitty);
        let exact = encode(kitty, &frame, (24, 8), (240, 160)).unwrap();
        let (image, colors) = encode_within(
            kitty,
            &frame,
            (24, 8),
            (240, 160),
            Some(exact.bytes() / 2),
            None,
        )
        .unwrap();
        assert_eq!(colors, Some(32));
        assert!(image.bytes() <= exact.bytes() / 2, "{}", image.bytes());
        let PaneImage::Kitty { transmit, .. } = &image else {
            panic!("kitty frames are shown by placeholders");
        };
        assert!(transmit.starts_with("\x1b_Ga=T,q=2,i=7365481,f=100,s=240,v=160,c=24,r=8,U=1"));
        let (_, colors) =
            encode_within(kitty, &frame, (24, 8), (240, 160), Some(100), None).unwrap();
        assert_eq!(colors, Some(8));
        // Told where to start (the exact frame did not fit last time): from
        // there down, without the exact encoding.
        let (image, colors) = encode_within(
            kitty,
            &frame,
            (24, 8),
            (240, 160),
            Some(usize::MAX),
            Some(16),
        )
        .unwrap();
        assert_eq!(colors, Some(16), "fits at once");
        let PaneImage::Kitty { transmit, .. } = &image else {
            panic!("kitty frames are shown by placeholders");
        };
        assert!(transmit.contains(",f=100,"));
    }

    #[test]
    fn patches_draw_the_picture_under_a_run_of_cells_again() {
        // A 40×20 frame (reduced) over 8×4 cells of 10×20 px: red left, blue right.
        let mut frame = Frame::background(40, 20, [0, 0, 255]);
        for px in frame.rgba.chunks_mut(4 * 20).step_by(2) {
            for p in px.chunks_mut(4) {
                p[..3].copy_from_slice(&[255, 0, 0]);
            }
        }
        let sixel = Encoding::new(Graphics::Sixel);
        let left = patch(sixel, &frame, (8, 4), (10, 20), (1, 2, 2)).unwrap();
        assert!(left.starts_with("\x1bP0;1;0q\"1;1;20;20#"), "{left:?}");
        assert!(left.contains(";2;100;0;0") && !left.contains(";2;0;0;100"));
        let right = patch(sixel, &frame, (8, 4), (10, 20), (6, 3, 2)).unwrap();
        assert!(right.contains(";2;0;0;100") && !right.contains(";2;100;0;0"));
        // Not through tmux (the whole image is sent again); iTerm2 as a PNG a
        // cell high.
        let through = Encoding {
            passthrough: true,
            ..sixel
        };
        assert_eq!(patch(through, &frame, (8, 4), (10, 20), (0, 0, 1)), None);
        let iterm = patch(
            Encoding::new(Graphics::Iterm2),
            &frame,
            (8, 4),
            (10, 20),
            (0, 0, 3),
        );
        assert!(iterm.unwrap().contains("width=3;height=1"));
        // Not for cells (text, kitty), nor outside the pane.
        assert_eq!(
            patch(
                Encoding::new(Graphics::Kitty),
                &frame,
                (8, 4),
                (10, 20),
                (0, 0, 1)
            ),
            None
        );
        assert_eq!(patch(sixel, &frame, (8, 4), (10, 20), (7, 0, 2)), None);
        assert_eq!(patch(sixel, &frame, (8, 4), (10, 20), (0, 4, 1)), None);
        assert_eq!(patch(sixel, &frame, (0, 0), (10, 20), (0, 0, 0)), None);
    }

    #[test]
    fn kitty_frames_fill_the_pane_with_placeholders() {
        let frame = Frame::background(20, 20, [0, 0, 0]);
        let img = encode(Encoding::new(Graphics::Kitty), &frame, (4, 2), (40, 40)).unwrap();
        let mut buf = Buffer::empty(Rect::new(0, 0, 6, 3));
        (&img).render(Rect::new(1, 1, 5, 2), &mut buf);
        let first = buf[(1, 1)].symbol();
        assert!(first.starts_with("\x1b_Ga=T,q=2,i=7365481,f=24,o=z,s=20,v=20,c=4,r=2,U=1"));
        assert!(first.ends_with(&kitty::placeholder(0, 0, KITTY_IMAGE_ID)));
        assert_eq!(
            buf[(4, 2)].symbol(),
            kitty::placeholder(1, 3, KITTY_IMAGE_ID)
        );
        assert_eq!(buf[(4, 2)].fg, Color::Rgb(0x70, 0x63, 0x69));
        // Outside the image's 4×2 cells nothing is drawn.
        assert_eq!(buf[(5, 1)].symbol(), " ");
    }

    #[test]
    fn kitty_frames_without_placeholders_are_placed_at_the_panes_first_cell() {
        let kitty = Encoding::new(Graphics::Kitty);
        let direct = Encoding {
            placeholders: false,
            ..kitty
        };
        assert!(image_in_one_cell(direct) && image_above_text(direct));
        assert!(!image_in_one_cell(kitty) && !image_above_text(kitty));
        assert!(!image_above_text(Encoding::new(Graphics::Sixel)));
        let frame = Frame::background(20, 20, [0, 0, 0]);
        let img = encode(direct, &frame, (4, 2), (40, 40)).unwrap();
        assert_eq!(img.cells(), (4, 2));
        let mut buf = Buffer::empty(Rect::new(0, 0, 6, 3));
        (&img).render(Rect::new(1, 1, 5, 2), &mut buf);
        // The first cell holds the whole image, placed where the draw puts the
        // cursor (that cell) and scaled to the 4×2 cells, below text; the pane
        // erased first (text there would show over it); no placeholder cells.
        let first = buf[(1, 1)].symbol();
        assert!(
            first.starts_with(
                "\x1b[4X\x1b[1B\x1b[4X\x1b[1B\x1b[2A\x1b_Ga=T,q=2,i=7365481,f=24,o=z,s=20,v=20,c=4,r=2,C=1,z=-1073741825,m=0;"
            ),
            "{first:?}"
        );
        assert!(first.ends_with("\x1b\\"));
        assert!(!first.contains(kitty::PLACEHOLDER) && !first.contains("U=1"));
        assert_eq!(img.bytes(), first.len());
        // The image's other cells are left to it; outside them nothing is drawn.
        assert_eq!(buf[(4, 2)].diff_option, CellDiffOption::Skip);
        assert_eq!(buf[(2, 1)].diff_option, CellDiffOption::Skip);
        assert_eq!(buf[(5, 1)].symbol(), " ");
        assert_eq!(buf[(5, 1)].diff_option, CellDiffOption::None);
        // Each frame goes under the same id, so it replaces the last one.
        let again = encode(
            direct,
            &Frame::background(10, 10, [9, 9, 9]),
            (4, 2),
            (40, 40),
        )
        .unwrap();
        let PaneImage::FirstCell { data, .. } = again else {
            panic!("placed directly from the first cell");
        };
        assert!(data.contains("\x1b_Ga=T,q=2,i=7365481,"));
    }
}
