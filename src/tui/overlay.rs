//! The view's overlays as the terminal's own text over the picture: the scale
//! bar (`├────┤` with its length, in the dataset's unit, on the row above), the
//! crosshair (arms in the cells around the one it points at, which stays
//! clear), each picked point's letter at the cell it projects to, the segment
//! between two picks (braille dots, only in the cells it crosses) and their
//! distance. Drawn as cells they stay sharp in text mode, cost no image bytes,
//! and moving the crosshair or picking asks for no new frame.
//!
//! Everything projects with the camera and the pixel size the shown frame was
//! drawn with ([`FrameView`]), mapped to cells by the pane's pixels per cell,
//! so the overlays stay on the picture the pane shows while newer frames are
//! on their way. [`layout`] only computes cells (tested on its own); [`draw`]
//! writes them into ratatui's buffer; [`rewrite`] says what the event loop
//! writes again over an image sent from the pane's first cell, which ratatui's
//! diff knows nothing of; [`onto_pixels`] draws them into a saved frame's
//! pixels instead. The pane's first cell is never used: it carries the image
//! itself for kitty, sixel and iTerm2.

use super::app::App;
use super::protocol::{Encoding, Graphics, PaneImage, image_in_one_cell};
use crate::camera::Camera;
use crate::render::Frame;
use crate::render::legend::{self, length_label, value_label};
use crate::render::pick::distance;
use crate::render::pipeline::{Overlays, draw_overlays};
use ratatui::buffer::{Buffer, Cell, CellDiffOption};
use ratatui::layout::Rect;
use ratatui::style::{Color, Modifier, Style};

/// What the shown frame was drawn with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameView {
    pub camera: Camera,
    /// The frame's size in pixels (a reduced frame's own, while moving).
    pub width: u32,
    pub height: u32,
}

/// What the overlays show.
#[derive(Debug, Clone, Default)]
pub struct Marks<'a> {
    /// The crosshair, as fractions of the view across and down.
    pub cursor: Option<(f64, f64)>,
    /// Picked points (two: joined, with their distance).
    pub picks: &'a [[f64; 3]],
    /// The unit lengths are labelled in (`m`, `ft`).
    pub unit: &'a str,
}

/// One overlay cell: where (the buffer's coordinates), what, and how. A style
/// without a background keeps the picture's (text mode).
#[derive(Debug, Clone, PartialEq)]
pub struct Mark {
    pub x: u16,
    pub y: u16,
    pub symbol: char,
    pub style: Style,
}

/// The scale bar and labels: light on dark, readable over any picture.
const LABEL: Style = Style::new()
    .fg(Color::White)
    .bg(Color::Black)
    .add_modifier(Modifier::BOLD);
/// The crosshair: white strokes over the picture.
const STROKE: Style = Style::new().fg(Color::White).add_modifier(Modifier::BOLD);
/// Picks, their segment and distance: yellow, as the tool panel's.
const PICK: Style = Style::new().fg(Color::Yellow).add_modifier(Modifier::BOLD);
const PICK_LABEL: Style = Style::new()
    .fg(Color::Black)
    .bg(Color::Yellow)
    .add_modifier(Modifier::BOLD);

/// The scale bar's share of the view's width at most, as the pixel one's.
const SCALE_BAR_SHARE: f64 = 0.25;

/// Pixels per cell across and down, for a frame of `view` over a pane of
/// `cols`×`rows` cells (`None` for an empty pane or frame).
fn pixels_per_cell(view: &FrameView, cols: u16, rows: u16) -> Option<(f64, f64)> {
    (cols > 0 && rows > 0 && view.width > 0 && view.height > 0).then(|| {
        (
            view.width as f64 / cols as f64,
            view.height as f64 / rows as f64,
        )
    })
}

/// The scale bar for a pane `cols`×`rows` showing `view`: its length in ground
/// units and in cells, caps included. The round length ([`legend::scale_bar`],
/// the pixel bar's choice) spans at most a quarter of the view; its caps (`├`,
/// `┤`) are drawn at the middle of their cells, so the bar spans one cell less
/// than it takes. `None` where the camera gives no scale or the pane has no
/// room for two cells.
pub fn scale_bar(view: &FrameView, cols: u16, rows: u16) -> Option<(f64, u16)> {
    let (ppc, _) = pixels_per_cell(view, cols, rows)?;
    let max_px = view.width as f64 * SCALE_BAR_SHARE;
    let (len, px) = legend::scale_bar(&view.camera, view.height, max_px)?;
    let cells = (px / ppc).round() + 1.0;
    (cells >= 2.0 && cells <= cols as f64 - 1.0).then_some((len, cells as u16))
}

/// The cell of the pane (`cols`×`rows`, from its top-left) where world point `p`
/// lands, or `None` when it is off the pane or behind the camera.
pub fn project(view: &FrameView, cols: u16, rows: u16, p: [f64; 3]) -> Option<(u16, u16)> {
    let (cx, cy) = pixels_per_cell(view, cols, rows)?;
    let [px, py] = view.camera.project(p, view.width, view.height)?;
    let (x, y) = ((px / cx).floor(), (py / cy).floor());
    (x >= 0.0 && y >= 0.0 && x < cols as f64 && y < rows as f64).then_some((x as u16, y as u16))
}

/// The cell a crosshair at fractions `(fx, fy)` of the pane points at.
pub fn cursor_cell((fx, fy): (f64, f64), cols: u16, rows: u16) -> (u16, u16) {
    let cell = |f: f64, n: u16| ((f.clamp(0.0, 1.0) * n as f64) as u16).min(n.saturating_sub(1));
    (cell(fx, cols), cell(fy, rows))
}

/// Dots of a braille cell, 2 across and 4 down: the bit of dot (column, row).
const BRAILLE: [[u8; 4]; 2] = [[0x01, 0x02, 0x04, 0x40], [0x08, 0x10, 0x20, 0x80]];

/// The braille cells of a line from `a` to `b` (pane pixels) on a pane of
/// `cols`×`rows` cells of `ppc` pixels: clipped to the pane (Liang–Barsky),
/// then stepped dot by dot; each cell's dots combined.
fn segment(
    a: [f64; 2],
    b: [f64; 2],
    ppc: (f64, f64),
    cols: u16,
    rows: u16,
) -> Vec<((u16, u16), char)> {
    // In dots: two across and four down a cell.
    let (w, h) = (cols as f64 * 2.0, rows as f64 * 4.0);
    let to_dots = |p: [f64; 2]| [p[0] / ppc.0 * 2.0, p[1] / ppc.1 * 4.0];
    let (p, q) = (to_dots(a), to_dots(b));
    let d = [q[0] - p[0], q[1] - p[1]];
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    // Keep t where lo <= p + t d < hi on both axes.
    for (pk, dk, hi) in [(p[0], d[0], w), (p[1], d[1], h)] {
        for (num, den) in [(pk, -dk), (hi - 1e-9 - pk, dk)] {
            if den == 0.0 {
                if num < 0.0 {
                    return Vec::new();
                }
            } else {
                let t = num / den;
                if den < 0.0 {
                    t0 = t0.max(t);
                } else {
                    t1 = t1.min(t);
                }
            }
        }
    }
    if !(t0 <= t1 && t0.is_finite() && t1.is_finite()) {
        return Vec::new();
    }
    let (s, e) = (
        [p[0] + d[0] * t0, p[1] + d[1] * t0],
        [p[0] + d[0] * t1, p[1] + d[1] * t1],
    );
    let n = ((e[0] - s[0]).abs().max((e[1] - s[1]).abs()).ceil() as usize).max(1);
    let mut cells: std::collections::BTreeMap<(u16, u16), u8> = Default::default();
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (s[0] + (e[0] - s[0]) * t, s[1] + (e[1] - s[1]) * t);
        let (dx, dy) = (x.floor().clamp(0.0, w - 1.0), y.floor().clamp(0.0, h - 1.0));
        let (dx, dy) = (dx as u32, dy as u32);
        *cells.entry(((dx / 2) as u16, (dy / 4) as u16)).or_default() |=
            BRAILLE[(dx % 2) as usize][(dy % 4) as usize];
    }
    cells
        .into_iter()
        .map(|(cell, bits)| (cell, char::from_u32(0x2800 + bits as u32).unwrap_or(' ')))
        .collect()
}

/// The overlay cells for `marks` over `pane` showing a frame of `view`, in the
/// buffer's coordinates, in the order they are drawn (later ones win a cell).
pub fn layout(view: &FrameView, marks: &Marks<'_>, pane: Rect) -> Vec<Mark> {
    let (cols, rows) = (pane.width, pane.height);
    let Some(ppc) = pixels_per_cell(view, cols, rows) else {
        return Vec::new();
    };
    let mut out: Vec<Mark> = Vec::new();
    let mut put = |x: u16, y: u16, symbol: char, style: Style| {
        out.push(Mark {
            x: pane.x + x,
            y: pane.y + y,
            symbol,
            style,
        })
    };
    // A text starting at (x, y), cut at the pane's right edge.
    let text = |put: &mut dyn FnMut(u16, u16, char, Style), x: u16, y: u16, s: &str, style| {
        for (k, c) in s.chars().enumerate() {
            let cx = x as usize + k;
            if cx >= cols as usize {
                break;
            }
            put(cx as u16, y, c, style);
        }
    };

    // The segment and the distance between two picks.
    if let [a, b] = marks.picks {
        let pa = view.camera.project(*a, view.width, view.height);
        let pb = view.camera.project(*b, view.width, view.height);
        if let (Some(pa), Some(pb)) = (pa, pb) {
            for ((x, y), c) in segment(pa, pb, ppc, cols, rows) {
                put(x, y, c, PICK);
            }
            let label = format!(" {} {} ", value_label(distance(*a, *b).d3), marks.unit);
            let mid = [(pa[0] + pb[0]) / 2.0 / ppc.0, (pa[1] + pb[1]) / 2.0 / ppc.1];
            let width = label.chars().count() as f64;
            if mid[0] >= 0.0 && mid[1] >= 0.0 && mid[0] < cols as f64 && mid[1] < rows as f64 {
                // Centred over the middle, one row above it, kept inside the pane.
                let x = (mid[0] - width / 2.0).clamp(0.0, (cols as f64 - width).max(0.0)) as u16;
                let y = (mid[1] as u16).saturating_sub(1);
                text(&mut put, x, y, &label, PICK_LABEL);
            }
        }
    }
    for (k, p) in marks.picks.iter().enumerate() {
        if let Some((x, y)) = project(view, cols, rows, *p) {
            put(x, y, ['A', 'B'][k.min(1)], PICK_LABEL);
        }
    }
    // The crosshair: arms around the cell it points at (two cells each way
    // across, as cells are about twice as high as wide), that cell left clear.
    if let Some(c) = marks.cursor {
        let (x, y) = cursor_cell(c, cols, rows);
        let (x, y) = (x as i32, y as i32);
        for (dx, dy, symbol) in [
            (-2, 0, '─'),
            (-1, 0, '─'),
            (1, 0, '─'),
            (2, 0, '─'),
            (0, -1, '│'),
            (0, 1, '│'),
        ] {
            let (cx, cy) = (x + dx, y + dy);
            if cx >= 0 && cy >= 0 && cx < cols as i32 && cy < rows as i32 {
                put(cx as u16, cy as u16, symbol, STROKE);
            }
        }
    }
    // The scale bar on the last row, its label on the one above, a cell in from
    // the left.
    if rows >= 3
        && let Some((len, cells)) = scale_bar(view, cols, rows)
    {
        let y = rows - 1;
        for k in 0..cells {
            let symbol = match k {
                0 => '├',
                k if k + 1 == cells => '┤',
                _ => '─',
            };
            put(1 + k, y, symbol, LABEL);
        }
        text(&mut put, 1, y - 1, &length_label(len, marks.unit), LABEL);
    }
    // The pane's first cell carries the image (kitty, sixel, iTerm2).
    out.retain(|m| (m.x, m.y) != (pane.x, pane.y));
    out
}

/// The overlay cells of `app`'s view over the cells `image` covers from the
/// top-left of `pane` (the view pane's inside); none before the first frame,
/// nor where the worker draws them into the frame's pixels.
pub fn of_app(app: &App, pane: Rect, image: &PaneImage) -> Vec<Mark> {
    let Some(view) = &app.frame.view.filter(|_| !app.overlays_in_pixels) else {
        return Vec::new();
    };
    let (w, h) = image.cells();
    let area = Rect::new(pane.x, pane.y, w, h).intersection(pane);
    let picks: Vec<[f64; 3]> = app.picks.iter().map(|p| p.position).collect();
    let marks = Marks {
        cursor: app.picking.then_some(app.cursor),
        picks: &picks,
        unit: &app.unit,
    };
    layout(view, &marks, area)
}

/// `frame` (drawn with `view`) with the overlays drawn into its pixels, as
/// `render` draws them: for a frame saved to a file, where there are no cells.
pub fn onto_pixels(frame: &Frame, view: &FrameView, marks: &Marks<'_>) -> Frame {
    let mut f = frame.clone();
    let crosshair = marks.cursor.map(|(x, y)| {
        let at = |v: f64, n: u32| ((v.clamp(0.0, 1.0) * n as f64) as u32).min(n.saturating_sub(1));
        (at(x, f.width), at(y, f.height))
    });
    let overlays = Overlays {
        marks: marks.picks,
        crosshair,
        legend: false,
        scale_bar: true,
    };
    draw_overlays(&mut f, &view.camera, &overlays, None, marks.unit);
    f
}

/// Writes `marks` into `buf`: each replaces its cell's symbol and, where its
/// style says, colours; cells the image skipped are written again.
pub fn draw(buf: &mut Buffer, marks: &[Mark]) {
    for m in marks {
        if let Some(cell) = buf.cell_mut((m.x, m.y)) {
            cell.set_char(m.symbol)
                .set_style(m.style)
                .set_diff_option(CellDiffOption::None);
        }
    }
}

/// The cells of `before` no longer drawn `now`.
fn removed(before: &[Mark], now: &[Mark]) -> Vec<(u16, u16)> {
    before
        .iter()
        .map(|m| (m.x, m.y))
        .filter(|p| !now.iter().any(|m| (m.x, m.y) == *p))
        .collect()
}

/// The cells of `cells` as runs along rows: (x, y, length), row-major.
fn runs(cells: &[(u16, u16)]) -> Vec<(u16, u16, u16)> {
    let mut sorted = cells.to_vec();
    sorted.sort_unstable_by_key(|&(x, y)| (y, x));
    sorted.dedup();
    let mut out: Vec<(u16, u16, u16)> = Vec::new();
    for (x, y) in sorted {
        match out.last_mut() {
            Some((rx, ry, n)) if *ry == y && *rx + *n == x => *n += 1,
            _ => out.push((x, y, 1)),
        }
    }
    out
}

/// What to write again after a draw over an image sent from the pane's first
/// cell `first` (sixel, iTerm2, kitty placed directly), of which ratatui's diff
/// knows nothing. After a new image (`image_sent`): every overlay cell, since
/// the image was drawn over them. When overlay cells went away (`before` →
/// `now`): sixel and iTerm2 pixels under them are gone, so the picture there
/// is drawn again, by `patch` (the escape string that draws a run `(x, y, n)`
/// of cells of the picture, [`super::protocol::patch`]) or, failing that, by
/// the whole image again followed by every overlay cell; kitty's image, below
/// text, shows again under blank cells. The cells come from `buf`, the buffer
/// just drawn, in the order to write them.
pub fn rewrite(
    buf: &Buffer,
    enc: Encoding,
    image_sent: bool,
    (before, now): (&[Mark], &[Mark]),
    first: (u16, u16),
    patch: &dyn Fn((u16, u16, u16)) -> Option<String>,
) -> Vec<(u16, u16, Cell)> {
    if !image_in_one_cell(enc) {
        return Vec::new();
    }
    let gone = removed(before, now);
    let mut out = Vec::new();
    let mut image_again = false;
    if !gone.is_empty() && !image_sent {
        if enc.graphics == Graphics::Kitty {
            out.extend(gone.iter().map(|&(x, y)| (x, y, Cell::default())));
        } else {
            let patches: Option<Vec<(u16, u16, String)>> = runs(&gone)
                .into_iter()
                .map(|r| patch(r).map(|s| (r.0, r.1, s)))
                .collect();
            match patches {
                Some(p) => out.extend(p.into_iter().map(|(x, y, s)| {
                    let mut c = Cell::default();
                    c.set_symbol(&s);
                    (x, y, c)
                })),
                None => {
                    image_again = true;
                    if let Some(c) = buf.cell(first) {
                        out.push((first.0, first.1, c.clone()));
                    }
                }
            }
        }
    }
    if image_sent || image_again {
        out.extend(
            now.iter()
                .filter_map(|m| buf.cell((m.x, m.y)).map(|c| (m.x, m.y, c.clone()))),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Looking straight down from 100 units at a 240×160 px frame.
    fn view() -> FrameView {
        FrameView {
            camera: Camera {
                distance: 100.0,
                pitch: -89.9f64.to_radians(),
                near: 1.0,
                far: 1000.0,
                ..Camera::default()
            },
            width: 240,
            height: 160,
        }
    }

    fn at(marks: &[Mark], x: u16, y: u16) -> Option<char> {
        marks
            .iter()
            .rev()
            .find(|m| (m.x, m.y) == (x, y))
            .map(|m| m.symbol)
    }

    fn row(marks: &[Mark], y: u16, width: u16) -> String {
        (0..width).map(|x| at(marks, x, y).unwrap_or(' ')).collect()
    }

    #[test]
    fn the_scale_bar_is_the_pixel_bars_length_in_cells() {
        let v = view();
        // 120×40 cells: 2×4 pixels a cell.
        let (len, cells) = scale_bar(&v, 120, 40).unwrap();
        let (len_px, px) = legend::scale_bar(&v.camera, 160, 60.0).unwrap();
        assert_eq!(len, len_px);
        assert_eq!(cells, (px / 2.0).round() as u16 + 1);
        assert!((2..=31).contains(&cells), "{cells}");
        // Drawn: caps at both ends, the label on the row above, one row.
        let marks = layout(
            &v,
            &Marks {
                unit: "m",
                ..Default::default()
            },
            Rect::new(0, 0, 120, 40),
        );
        let bar = row(&marks, 39, 120);
        let expected = format!(" ├{}┤", "─".repeat(cells as usize - 2));
        assert_eq!(bar.trim_end(), expected);
        let label = row(&marks, 38, 120);
        assert_eq!(label.trim(), length_label(len, "m"));
        assert!(label.trim().ends_with(" m"), "{label}");
        assert_eq!(row(&marks, 37, 120).trim(), "", "one row of label");
    }

    #[test]
    fn picks_land_on_their_cells_with_the_segment_and_distance_between() {
        let v = view();
        let pane = Rect::new(10, 5, 120, 40);
        let target = v.camera.target.to_array();
        let a = target;
        let b = [target[0] + 20.0, target[1], target[2]];
        // The target is at the centre: pixel (120, 80), cell (60, 20).
        assert_eq!(project(&v, 120, 40, a), Some((60, 20)));
        let (bx, by) = project(&v, 120, 40, b).unwrap();
        assert!(bx > 60 && by.abs_diff(20) <= 1, "{bx} {by}");
        let marks = layout(
            &v,
            &Marks {
                picks: &[a, b],
                unit: "ft",
                ..Default::default()
            },
            pane,
        );
        assert_eq!(at(&marks, 70, 25), Some('A'));
        assert_eq!(at(&marks, 10 + bx, 5 + by), Some('B'));
        // Braille dots between them, and the distance above the middle.
        let between: Vec<char> = (71..10 + bx).filter_map(|x| at(&marks, x, 25)).collect();
        assert!(
            !between.is_empty()
                && between
                    .iter()
                    .all(|c| ('\u{2801}'..='\u{28ff}').contains(c)),
            "{between:?}"
        );
        let text = row(&marks, 24, 140);
        assert!(text.contains(" 20.0 ft "), "{text}");
        // Off the pane or behind the camera: no mark.
        assert_eq!(project(&v, 120, 40, [1e9, 0.0, 0.0]), None);
    }

    #[test]
    fn the_crosshair_surrounds_its_cell_and_leaves_it_clear() {
        let v = view();
        let marks = layout(
            &v,
            &Marks {
                cursor: Some((0.5, 0.5)),
                unit: "m",
                ..Default::default()
            },
            Rect::new(0, 0, 120, 40),
        );
        assert_eq!(cursor_cell((0.5, 0.5), 120, 40), (60, 20));
        assert_eq!(at(&marks, 60, 20), None);
        assert_eq!(at(&marks, 58, 20), Some('─'));
        assert_eq!(at(&marks, 62, 20), Some('─'));
        assert_eq!(at(&marks, 60, 19), Some('│'));
        assert_eq!(at(&marks, 60, 21), Some('│'));
        // In a corner the arms are cut, and the pane's first cell stays the image's.
        let corner = layout(
            &v,
            &Marks {
                cursor: Some((0.0, 0.0)),
                unit: "m",
                ..Default::default()
            },
            Rect::new(3, 2, 120, 40),
        );
        assert_eq!(at(&corner, 3, 2), None);
        assert_eq!(at(&corner, 4, 2), Some('─'));
        assert_eq!(at(&corner, 3, 3), Some('│'));
    }

    #[test]
    fn overlay_cells_over_an_image_sent_from_the_first_cell_are_written_again() {
        let mut buf = Buffer::empty(Rect::new(0, 0, 44, 14));
        buf[(2, 1)].set_symbol("IMAGE");
        let mark = |x, y| Mark {
            x,
            y,
            symbol: '─',
            style: STROKE,
        };
        let before = [mark(5, 5), mark(6, 5)];
        let now = [mark(6, 5), mark(7, 5)];
        draw(&mut buf, &now);
        let sixel = Encoding::new(Graphics::Sixel);
        let at = |cells: &[(u16, u16, Cell)]| -> Vec<(u16, u16, String)> {
            cells
                .iter()
                .map(|(x, y, c)| (*x, *y, c.symbol().to_string()))
                .collect()
        };
        let none = |_: (u16, u16, u16)| None;
        let patch = |(x, y, n): (u16, u16, u16)| Some(format!("P{x},{y},{n}"));
        // A cell went away: the picture under it drawn again, nothing else.
        assert_eq!(
            at(&rewrite(
                &buf,
                sixel,
                false,
                (&before, &now),
                (2, 1),
                &patch
            )),
            [(5, 5, "P5,5,1".into())]
        );
        // Runs along rows: one patch each.
        let arms = [mark(5, 5), mark(6, 5), mark(7, 5), mark(6, 4), mark(9, 5)];
        assert_eq!(
            at(&rewrite(&buf, sixel, false, (&arms, &[]), (2, 1), &patch)),
            [
                (6, 4, "P6,4,1".into()),
                (5, 5, "P5,5,3".into()),
                (9, 5, "P9,5,1".into())
            ]
        );
        // Without patches: the image again, then every overlay cell over it.
        assert_eq!(
            at(&rewrite(&buf, sixel, false, (&before, &now), (2, 1), &none)),
            [
                (2, 1, "IMAGE".into()),
                (6, 5, "─".into()),
                (7, 5, "─".into())
            ]
        );
        // A new image (sent by the draw): the overlay cells over it.
        assert_eq!(
            at(&rewrite(&buf, sixel, true, (&before, &now), (2, 1), &patch)),
            [(6, 5, "─".into()), (7, 5, "─".into())]
        );
        // Nothing went away, no new image: nothing to write.
        assert!(rewrite(&buf, sixel, false, (&now, &now), (2, 1), &patch).is_empty());
        // Kitty placed directly (below text): the cell left is blanked.
        let direct = Encoding {
            placeholders: false,
            ..Encoding::new(Graphics::Kitty)
        };
        assert_eq!(
            at(&rewrite(
                &buf,
                direct,
                false,
                (&before, &now),
                (2, 1),
                &patch
            )),
            [(5, 5, " ".into())]
        );
        // Cells (text, kitty placeholders): ratatui's diff does it all.
        for g in [Graphics::Halfblocks, Graphics::Kitty] {
            let enc = Encoding::new(g);
            assert!(rewrite(&buf, enc, true, (&before, &now), (2, 1), &patch).is_empty());
        }
    }

    #[test]
    fn odd_sizes_draw_what_fits_and_never_panic() {
        let v = view();
        let far = [[1e12, -1e12, 5.0], [f64::MAX, 0.0, f64::NAN]];
        for (w, h) in [(0, 0), (1, 1), (2, 1), (1, 5), (3, 3), (5, 2), (400, 200)] {
            for cursor in [(0.0, 0.0), (1.0, 1.0), (0.5, 0.5), (f64::NAN, 2.0)] {
                let marks = Marks {
                    cursor: Some(cursor),
                    picks: &far,
                    unit: "units",
                };
                let pane = Rect::new(0, 0, w, h);
                let cells = layout(&v, &marks, pane);
                assert!(cells.iter().all(|m| m.x < w && m.y < h), "{w}×{h}");
                let picks = [v.camera.target.to_array(), far[0]];
                let cells = layout(
                    &v,
                    &Marks {
                        picks: &picks,
                        ..marks
                    },
                    pane,
                );
                assert!(cells.iter().all(|m| m.x < w && m.y < h), "{w}×{h}");
                let mut buf = Buffer::empty(Rect::new(0, 0, w.max(1), h.max(1)));
                draw(&mut buf, &cells);
            }
        }
        let empty = FrameView {
            width: 0,
            height: 0,
            ..v
        };
        assert!(layout(&empty, &Marks::default(), Rect::new(0, 0, 80, 24)).is_empty());
        assert_eq!(scale_bar(&v, 2, 40), None);
    }
}
