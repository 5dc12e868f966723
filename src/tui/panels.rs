//! The inspector's tool panel: the legend (classes with their counts, the
//! selected row and which are hidden; or the ramp with its values), the picked
//! points with every attribute in source units, and the distances between the
//! last two. File-derived text (band names) passes through [`sanitize`].

use super::app::{App, format_xyz};
use crate::render::classes;
use crate::render::color::unpack_rgb;
use crate::render::legend::Legend;
use crate::render::legend::{tick_label, ticks, value_label};
use crate::render::pick::distance;
use crate::text::{count, sanitize};
use ratatui::Frame;
use ratatui::layout::Rect;
use ratatui::style::{Color, Style, Stylize};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Paragraph};

/// Cells of the ramp bar.
pub(crate) const RAMP_CELLS: usize = 24;

/// Eighth blocks as high as each count against the largest, each in its
/// ramp cell's colour (an empty cell a space).
fn sparkline(h: &[u32], lut: &[u32; 256]) -> Vec<Span<'static>> {
    const BARS: [&str; 8] = ["▁", "▂", "▃", "▄", "▅", "▆", "▇", "█"];
    let top = h.iter().copied().max().unwrap_or(0).max(1) as f64;
    h.iter()
        .enumerate()
        .map(|(i, &c)| {
            if c == 0 {
                return Span::from(" ");
            }
            let k = ((c as f64 / top * 8.0).ceil() as usize).clamp(1, 8) - 1;
            let [r, g, b] = unpack_rgb(lut[i * 255 / (h.len() - 1).max(1)]);
            Span::from(BARS[k]).fg(Color::Rgb(r, g, b))
        })
        .collect()
}

/// The panel's lines.
pub fn lines(app: &App) -> Vec<Line<'static>> {
    let mut out: Vec<Line<'static>> = Vec::new();
    match app.legend() {
        Some(Legend::Classes(entries)) => {
            if entries.is_empty() {
                out.push(Line::from("no class counts recorded (convert again)").dark_gray());
            }
            for (k, e) in entries.iter().enumerate() {
                let [r, g, b] = unpack_rgb(e.color);
                let selected = k == app.legend_row.min(entries.len() - 1);
                let mut text = Span::from(format!(
                    " {:>3} {:<20} {:>13}",
                    e.code,
                    e.name,
                    count(e.count)
                ));
                if !e.shown {
                    text = text.dark_gray().crossed_out();
                }
                let mark = if selected { "▶" } else { " " };
                let mut line = Line::from(vec![
                    Span::from(mark),
                    Span::from("██").fg(Color::Rgb(r, g, b)),
                    text,
                ]);
                if selected {
                    line = line.bold();
                }
                out.push(line);
            }
        }
        Some(Legend::Ramp {
            title: band,
            ramp,
            lo,
            hi,
        }) => {
            let lut = ramp.lut();
            let bar: Vec<Span<'static>> = (0..RAMP_CELLS)
                .map(|i| {
                    let [r, g, b] = unpack_rgb(lut[i * 255 / (RAMP_CELLS - 1)]);
                    Span::from("█").fg(Color::Rgb(r, g, b))
                })
                .collect();
            out.push(Line::from(format!("{} ({})", sanitize(&band), ramp.name())));
            out.push(Line::from(bar));
            // The drawn points' values under the colours they get.
            let h = &app.frame.histogram;
            if h.len() == RAMP_CELLS && h.iter().any(|&c| c > 0) {
                out.push(Line::from(sparkline(h, lut)));
            }
            let t = ticks(lo, hi, 3);
            out.push(Line::from(format!(
                "{:<10}{:^6}{:>10}",
                tick_label(t[0], hi - lo),
                tick_label(t[1], hi - lo),
                tick_label(t[2], hi - lo)
            )));
        }
        None => {}
    }
    if app.frame.units_per_pixel.is_finite() && app.frame.units_per_pixel > 0.0 {
        out.push(
            Line::from(format!(
                "1 px ≈ {} {} at the centre",
                value_label(app.frame.units_per_pixel),
                app.unit
            ))
            .dark_gray(),
        );
    }
    for (k, p) in app.picks.iter().enumerate() {
        let label = ["A", "B"][k.min(1)];
        out.push(Line::from(vec![
            Span::from(format!("{label} ")).bold().yellow(),
            Span::from(format_xyz(p.position)),
        ]));
    }
    if let Some(p) = app.picks.last() {
        let attrs: Vec<String> = p
            .attributes
            .iter()
            .map(|(n, v)| {
                let mut s = format!("{} {}", sanitize(n), value_text(*v));
                if n == "classification"
                    && let Some(c) = classes::code_of(*v as f32)
                {
                    s.push_str(&format!(" ({})", classes::name(c)));
                }
                s
            })
            .collect();
        for chunk in attrs.chunks(2) {
            out.push(Line::from(format!("  {}", chunk.join(" · "))));
        }
    }
    if let [a, b] = &app.picks[..] {
        let d = distance(a.position, b.position);
        out.push(
            Line::from(format!(
                "A→B 3D {} · horizontal {} · vertical {:+.3} {}",
                value_label(d.d3),
                value_label(d.horizontal),
                d.vertical,
                app.unit
            ))
            .yellow(),
        );
    }
    out
}

/// An attribute's value: whole numbers without decimals, large ones (GPS
/// time) with all their digits.
fn value_text(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{v:.0}")
    } else if v.abs() >= 1e4 {
        format!("{v:.6}")
    } else {
        value_label(v)
    }
}

/// Rows the panel wants (its lines and border), at most `cap`.
pub fn height(app: &App, cap: u16) -> u16 {
    let n = lines(app).len() as u16;
    if n == 0 { 0 } else { (n + 2).min(cap) }
}

/// Draws the panel.
pub fn draw(f: &mut Frame, app: &App, area: Rect) {
    if area.height == 0 {
        return;
    }
    let title = match app.settings.style.mode {
        crate::render::ColorMode::Classification => " classes (, . select · space show/hide) ",
        _ if app.picks.is_empty() => " legend ",
        _ => " legend · picks ",
    };
    let block = Block::bordered().title(Line::from(Span::from(title).bold()));
    let inner = block.inner(area);
    f.render_widget(block, area);
    f.render_widget(Paragraph::new(lines(app)).style(Style::new()), inner);
}
