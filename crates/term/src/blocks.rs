//! Unicode half-blocks, the picture every terminal draws: a cell is two pixels,
//! the upper one the foreground of `▀`, the lower one its background, in 24-bit
//! colour. One path for `preview` (an escape string, [`Blocks::ansi`]) and the
//! inspector (cells it puts in its own buffer, [`Blocks::cells`]).
//!
//! Our own rather than viuer's or ratatui-image's (each had one, and they
//! differed): each pixel is the mean of the frame pixels it covers, a box filter,
//! so a frame rendered larger than the cells (the inspector renders at the
//! terminal's cell size) keeps thin lines and single points as blended colour
//! instead of dropping them between samples; a frame of exactly two pixels a
//! cell is taken as it is. The escape string sets a colour only when it changes,
//! and a cell whose two pixels agree is a space on its background: fewer bytes
//! on a slow link.

use crate::Rgba;
use std::fmt::Write;

/// An RGB colour.
pub type Colour = [u8; 3];

/// One cell: its upper and lower pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cell {
    pub upper: Colour,
    pub lower: Colour,
}

impl Cell {
    /// The character the cell shows: `▀`, or a space when both halves agree (the
    /// background alone draws it).
    pub fn symbol(&self) -> char {
        if self.upper == self.lower { ' ' } else { '▀' }
    }
}

/// A picture as `cols` × `rows` half-block cells, row by row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Blocks {
    pub cols: u16,
    pub rows: u16,
    pub cells: Vec<Cell>,
}

impl Blocks {
    /// `frame` over `cols` × `rows` cells (`cols` × 2·`rows` pixels, each the
    /// mean of the frame pixels it covers; a frame smaller than that is
    /// enlarged by repeating pixels).
    pub fn of(frame: &Rgba<'_>, cols: u16, rows: u16) -> Blocks {
        let (w, h) = (cols as usize, rows as usize * 2);
        let (fw, fh) = (frame.width as usize, frame.height as usize);
        let mut cells = vec![
            Cell {
                upper: [0; 3],
                lower: [0; 3],
            };
            w * rows as usize
        ];
        if w == 0 || h == 0 || fw == 0 || fh == 0 || frame.rgba.len() < fw * fh * 4 {
            return Blocks { cols, rows, cells };
        }
        // The frame columns each pixel column covers: [x0, x1).
        let span = |i: usize, n: usize, f: usize| {
            let a = i * f / n;
            (a, ((i + 1) * f / n).max(a + 1))
        };
        let xs: Vec<(usize, usize)> = (0..w).map(|x| span(x, w, fw)).collect();
        for y in 0..h {
            let (y0, y1) = span(y, h, fh);
            for (x, &(x0, x1)) in xs.iter().enumerate() {
                let mut sum = [0u64; 3];
                for row in y0..y1 {
                    let line = &frame.rgba[(row * fw + x0) * 4..(row * fw + x1) * 4];
                    for px in line.chunks_exact(4) {
                        sum[0] += px[0] as u64;
                        sum[1] += px[1] as u64;
                        sum[2] += px[2] as u64;
                    }
                }
                let n = ((x1 - x0) * (y1 - y0)) as u64;
                // Rounded to the nearest.
                let c = sum.map(|s| ((s + n / 2) / n) as u8);
                let cell = &mut cells[(y / 2) * w + x];
                if y % 2 == 0 {
                    cell.upper = c;
                } else {
                    cell.lower = c;
                }
            }
        }
        Blocks { cols, rows, cells }
    }

    /// The cells of row `r`.
    pub fn row(&self, r: u16) -> &[Cell] {
        let w = self.cols as usize;
        &self.cells[r as usize * w..(r as usize + 1) * w]
    }

    /// The picture as text with 24-bit colour escapes, a line a row, the
    /// colours reset before each line break (so a scroll does not paint the new
    /// line); the cursor ends below the last row.
    pub fn ansi(&self) -> String {
        let mut s = String::with_capacity(self.cells.len() * 8);
        for r in 0..self.rows {
            let (mut fg, mut bg): (Option<Colour>, Option<Colour>) = (None, None);
            for cell in self.row(r) {
                let symbol = cell.symbol();
                if bg != Some(cell.lower) {
                    let [r, g, b] = cell.lower;
                    let _ = write!(s, "\x1b[48;2;{r};{g};{b}m");
                    bg = Some(cell.lower);
                }
                if symbol != ' ' && fg != Some(cell.upper) {
                    let [r, g, b] = cell.upper;
                    let _ = write!(s, "\x1b[38;2;{r};{g};{b}m");
                    fg = Some(cell.upper);
                }
                s.push(symbol);
            }
            s.push_str("\x1b[0m\n");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> Vec<u8> {
        let mut v = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let [r, g, b] = f(x, y);
                v.extend_from_slice(&[r, g, b, 255]);
            }
        }
        v
    }

    #[test]
    fn two_pixels_a_cell_are_taken_as_they_are() {
        let px = frame(3, 4, |x, y| [x as u8 * 50, y as u8 * 60, 7]);
        let b = Blocks::of(
            &Rgba {
                width: 3,
                height: 4,
                rgba: &px,
            },
            3,
            2,
        );
        assert_eq!(b.cells.len(), 6);
        assert_eq!(
            b.cells[0],
            Cell {
                upper: [0, 0, 7],
                lower: [0, 60, 7]
            }
        );
        assert_eq!(
            b.cells[5],
            Cell {
                upper: [100, 120, 7],
                lower: [100, 180, 7]
            }
        );
    }

    #[test]
    fn a_larger_frame_is_averaged_and_a_thin_line_survives() {
        // 40×40 black with one white column at x = 13: over 4×2 cells, each
        // pixel covers 10×10 frame pixels, so the line shows as a tenth of white
        // (sampling one pixel in ten would lose it).
        let px = frame(40, 40, |x, _| if x == 13 { [255; 3] } else { [0; 3] });
        let b = Blocks::of(
            &Rgba {
                width: 40,
                height: 40,
                rgba: &px,
            },
            4,
            2,
        );
        assert_eq!(b.cells[1].upper, [26; 3]);
        assert_eq!(b.cells[0].upper, [0; 3]);
        assert_eq!(b.cells[5].lower, [26; 3]);
    }

    #[test]
    fn a_smaller_frame_is_enlarged_and_odd_sizes_cover_every_pixel() {
        let px = frame(2, 2, |x, y| [(x * 100 + y * 10) as u8, 0, 0]);
        let b = Blocks::of(
            &Rgba {
                width: 2,
                height: 2,
                rgba: &px,
            },
            4,
            2,
        );
        assert_eq!(b.cells[0].upper, [0, 0, 0]);
        assert_eq!(b.cells[3].upper, [100, 0, 0]);
        assert_eq!(b.cells[7].lower, [110, 0, 0]);
        // 7×5 into 3×2 cells: no panic, every cell set from the frame.
        let px = frame(7, 5, |_, _| [9, 9, 9]);
        let b = Blocks::of(
            &Rgba {
                width: 7,
                height: 5,
                rgba: &px,
            },
            3,
            2,
        );
        assert!(
            b.cells
                .iter()
                .all(|c| c.upper == [9; 3] && c.lower == [9; 3])
        );
        // Nothing to draw: black cells, no panic.
        let b = Blocks::of(
            &Rgba {
                width: 0,
                height: 0,
                rgba: &[],
            },
            3,
            2,
        );
        assert_eq!(b.cells.len(), 6);
    }

    #[test]
    fn colours_are_written_only_when_they_change() {
        // Row 0: two cells of one colour pair, then a cell whose halves agree.
        let b = Blocks {
            cols: 3,
            rows: 1,
            cells: vec![
                Cell {
                    upper: [1, 2, 3],
                    lower: [4, 5, 6],
                },
                Cell {
                    upper: [1, 2, 3],
                    lower: [4, 5, 6],
                },
                Cell {
                    upper: [4, 5, 6],
                    lower: [4, 5, 6],
                },
            ],
        };
        assert_eq!(b.ansi(), "\x1b[48;2;4;5;6m\x1b[38;2;1;2;3m▀▀ \x1b[0m\n");
    }
}
