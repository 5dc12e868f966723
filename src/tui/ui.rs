//! The inspector's layout, drawn with ratatui from the [`App`] state: the parts
//! table, the selected part's bands and pyramid levels, memory gauges, the view
//! pane with the latest frame and its overlays (`overlay`: scale bar,
//! crosshair, picks), the status line, and the `?` help overlay. Drawing
//! only copies: frames arrive already encoded from the render worker. Every text
//! that came from a file passes through [`sanitize`] first.

use super::app::App;
use super::keys::HELP;
use super::protocol::PaneImage;
use crate::store::compression_name;
use crate::text::{bytes, count, sanitize};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style, Stylize};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Cell, Clear, Gauge, Paragraph, Row, Table, TableState};

/// Where things go on screen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Areas {
    pub parts: Rect,
    pub bands: Rect,
    pub levels: Rect,
    /// The legend and picked points (empty when there is nothing to show).
    pub tools: Rect,
    pub memory: Rect,
    /// The view pane's border, and inside it the frame.
    pub view: Rect,
    pub view_inner: Rect,
    pub status: Rect,
    pub hint: Rect,
}

/// Splits the screen. The left column holds the panels, the view takes the rest.
pub fn areas(area: Rect, app: &App) -> Areas {
    let [main, status, hint] = Layout::vertical([
        Constraint::Min(3),
        Constraint::Length(1),
        Constraint::Length(1),
    ])
    .areas(area);
    let left_width = (area.width * 2 / 5).clamp(20.min(area.width), 72);
    let [left, view] =
        Layout::horizontal([Constraint::Length(left_width), Constraint::Min(1)]).areas(main);
    let part = app.current_part().map(|(_, p)| p);
    let n_parts = app.part_ids().len() as u16;
    let mut n_bands = part.map_or(0, |p| p.bands.len()) as u16;
    if app.dataset.source().is_some() {
        // The file's fields (after x, y, z), in the source's panels.
        n_bands = app.dataset.totals().bands.len().saturating_sub(3) as u16;
    }
    let [parts, bands, levels, tools, memory] = Layout::vertical([
        Constraint::Length(n_parts.min(8) + 5),
        Constraint::Length(n_bands + 3),
        Constraint::Min(4),
        Constraint::Length(super::panels::height(app, 18)),
        Constraint::Length(4),
    ])
    .areas(left);
    let view_inner = Block::bordered().inner(view);
    Areas {
        parts,
        bands,
        levels,
        tools,
        memory,
        view,
        view_inner,
        status,
        hint,
    }
}

fn title(s: impl Into<String>) -> Line<'static> {
    Line::from(Span::from(s.into()).bold())
}

fn header(cells: &[&'static str]) -> Row<'static> {
    Row::new(cells.iter().map(|c| Cell::from(*c)))
        .style(Style::new().add_modifier(Modifier::BOLD | Modifier::UNDERLINED))
}

/// Draws the whole screen; `image` is the latest encoded frame, if any.
pub fn draw(f: &mut Frame, app: &App, image: Option<&PaneImage>) {
    let a = areas(f.area(), app);
    match app.dataset.source() {
        Some(src) => draw_source(f, app, src.as_ref(), [a.parts, a.bands, a.levels]),
        None => {
            draw_parts(f, app, a.parts);
            draw_bands(f, app, a.bands);
            draw_levels(f, app, a.levels);
        }
    }
    super::panels::draw(f, app, a.tools);
    draw_memory(f, app, a.memory);

    let view_title = format!(" view · {} ", app.protocol);
    let mut view_block = Block::bordered().title(title(view_title));
    if !app.message.is_empty() {
        view_block =
            view_block.title_bottom(Line::from(format!(" {} ", sanitize(&app.message))).yellow());
    }
    f.render_widget(view_block, a.view);
    match image {
        Some(img) => {
            f.render_widget(img, a.view_inner);
            // The scale bar, crosshair and picks as cells over the picture.
            let marks = super::overlay::of_app(app, a.view_inner, img);
            super::overlay::draw(f.buffer_mut(), &marks);
        }
        // Not drawn under the help (a kitty image placed directly would cover it).
        None if app.show_help => {}
        None => f.render_widget(
            Paragraph::new("rendering the first frame…").dark_gray(),
            a.view_inner,
        ),
    }

    f.render_widget(
        Paragraph::new(app.status_line()).style(Style::new().fg(Color::Black).bg(Color::Cyan)),
        a.status,
    );
    let hint = Line::from(vec![
        Span::from(app.timing_line()),
        Span::from(" · "),
        Span::from("?").bold(),
        Span::from(" help "),
        Span::from("q").bold(),
        Span::from(" quit"),
    ]);
    f.render_widget(Paragraph::new(hint), a.hint);

    if app.show_help {
        draw_help(f, f.area());
    }
}

/// The parts, bands and levels panels of a dataset drawn from another
/// format's tiles (a COPC file): the file, its fields, and the octree's depths
/// as far as its hierarchy was read, with the nodes loaded at each.
fn draw_source(f: &mut Frame, app: &App, src: &dyn crate::store::TileSource, areas: [Rect; 3]) {
    let ds = &app.dataset;
    let t = ds.totals();
    let stats = src.stats();
    let name = ds
        .path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| ds.path.display().to_string());
    let b = &t.bounds;
    let lines = vec![
        Line::from(format!(
            "{} · {} points · {}",
            sanitize(&name),
            count(t.points),
            bytes(t.bytes)
        )),
        Line::from(format!("bounds {}", bounds_text(b))),
        Line::from(format!(
            "crs {}",
            t.crs.as_deref().map(sanitize).unwrap_or_else(|| "-".into())
        ))
        .dark_gray(),
    ];
    f.render_widget(
        Paragraph::new(lines).block(Block::bordered().title(title(format!(" {} ", stats.format)))),
        areas[0],
    );
    let rows: Vec<Row> = t
        .bands
        .iter()
        .skip(3)
        .map(|n| Row::new(vec![Cell::from(sanitize(n)), Cell::from("LAS")]))
        .collect();
    let bands = Table::new(rows, [Constraint::Fill(1), Constraint::Length(8)])
        .header(header(&["band", "type"]))
        .block(Block::bordered().title(title(" bands ")));
    f.render_widget(bands, areas[1]);
    let rows: Vec<Row> = stats
        .depths
        .iter()
        .enumerate()
        .map(|(d, (nodes, points))| {
            let loaded = app
                .frame
                .loaded
                .iter()
                .filter(|((part, level), _)| *part == crate::store::SOURCE_PART && *level == d)
                .map(|(_, n)| *n)
                .sum::<usize>();
            Row::new(vec![
                Cell::from(d.to_string()),
                Cell::from(count(*nodes as u64)),
                Cell::from(count(*points)),
                Cell::from(format!("{loaded}/{nodes}")),
            ])
        })
        .collect();
    let (read, unread) = stats.pages;
    let levels = Table::new(
        rows,
        [
            Constraint::Length(6),
            Constraint::Length(8),
            Constraint::Length(12),
            Constraint::Fill(1),
        ],
    )
    .header(header(&["depth", "nodes", "points", "loaded"]))
    .block(Block::bordered().title(title(format!(
        " octree: nodes reached · {read} page(s) read, {unread} not yet "
    ))));
    f.render_widget(levels, areas[2]);
}

fn draw_parts(f: &mut Frame, app: &App, area: Rect) {
    let ids = app.part_ids();
    let rows: Vec<Row> = ids
        .iter()
        .filter_map(|&id| app.dataset.part(id))
        .map(|p| {
            let name = p
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| p.path.display().to_string());
            let b = &p.meta.bounds;
            let extent = format!(
                "{}×{}×{}",
                short_extent(b.max[0] - b.min[0]),
                short_extent(b.max[1] - b.min[1]),
                short_extent(b.max[2] - b.min[2])
            );
            Row::new(vec![
                Cell::from(sanitize(&name)),
                Cell::from(count(p.meta.point_count)),
                Cell::from(extent),
                Cell::from(bytes(p.file_bytes)),
            ])
        })
        .collect();
    let part = app.current_part().map(|(_, p)| p);
    let source = part
        .and_then(|p| p.meta.source.as_deref())
        .map(sanitize)
        .unwrap_or_else(|| "-".into());
    let crs = part
        .and_then(|p| p.meta.crs.as_deref())
        .map(sanitize)
        .unwrap_or_else(|| "-".into());
    let n = ids.len();
    let total = app.dataset.part_count();
    let heading = if n < total {
        format!(" parts ({}/{n} reached of {total}) ", app.part + 1)
    } else if n > 1 {
        format!(" parts ({}/{n}) ", app.part + 1)
    } else {
        " parts ".to_string()
    };
    let block = Block::bordered().title(title(&heading));
    let inner = block.inner(area);
    f.render_widget(block, area);
    let [table_area, bounds_line, detail] = Layout::vertical([
        Constraint::Min(1),
        Constraint::Length(1),
        Constraint::Length(1),
    ])
    .areas(inner);
    let table = Table::new(
        rows,
        [
            Constraint::Fill(2),
            Constraint::Length(11),
            Constraint::Fill(3),
            Constraint::Length(10),
        ],
    )
    .header(header(&["file", "points", "extent x×y×z", "bytes"]))
    .row_highlight_style(Style::new().reversed());
    // The table scrolls to keep the selected part in view.
    let mut state = TableState::new().with_selected(Some(app.part));
    f.render_stateful_widget(table, table_area, &mut state);
    // The selected part's bounds in full (the table shows each part's extent).
    let bounds = part.map_or_else(|| "-".to_string(), |p| bounds_text(&p.meta.bounds));
    f.render_widget(Paragraph::new(format!("bounds {bounds}")), bounds_line);
    f.render_widget(
        Paragraph::new(format!("source {source} · crs {crs}")).dark_gray(),
        detail,
    );
}

/// `x LO..HI  y LO..HI  z LO..HI`, for a bounds line.
fn bounds_text(b: &crate::points::Bounds) -> String {
    (0..3)
        .map(|a| {
            format!(
                "{} {}..{}",
                ["x", "y", "z"][a],
                coordinate(b.min[a]),
                coordinate(b.max[a])
            )
        })
        .collect::<Vec<_>>()
        .join("  ")
}

/// A coordinate for the bounds line: whole units from 10,000 up (georeferenced
/// eastings and northings), else one or two decimals.
fn coordinate(v: f64) -> String {
    if v.abs() >= 1e4 {
        format!("{v:.0}")
    } else if v.abs() >= 100.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

/// A length in at most about 6 characters: `405`, `12.5`, `1.2k`, `3.4M`.
fn short_extent(v: f64) -> String {
    let a = v.abs();
    if !a.is_finite() {
        "-".into()
    } else if a >= 1e6 {
        format!("{:.1}M", v / 1e6)
    } else if a >= 1e4 {
        format!("{:.1}k", v / 1e3)
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

/// A value in at most about 9 characters: 3 decimals for small magnitudes, fewer
/// as they grow (coordinates of a few hundred thousand keep 2).
fn short(v: f64) -> String {
    let a = v.abs();
    if a >= 1e7 {
        format!("{v:.3e}")
    } else if a >= 1e5 {
        format!("{v:.1}")
    } else if a >= 100.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn draw_bands(f: &mut Frame, app: &App, area: Rect) {
    let rows: Vec<Row> = app
        .current_part()
        .map(|(_, p)| {
            p.bands
                .iter()
                .map(|b| {
                    Row::new(vec![
                        Cell::from(sanitize(&b.name)),
                        Cell::from("Float32"),
                        Cell::from(match b.range {
                            Some((lo, hi)) => format!("{} .. {}", short(lo), short(hi)),
                            None => "-".into(),
                        }),
                    ])
                })
                .collect()
        })
        .unwrap_or_default();
    let t = Table::new(
        rows,
        [
            Constraint::Fill(1),
            Constraint::Length(8),
            Constraint::Fill(1),
        ],
    )
    .header(header(&["band", "type", "range"]))
    .block(Block::bordered().title(title(" bands ")));
    f.render_widget(t, area);
}

fn draw_levels(f: &mut Frame, app: &App, area: Rect) {
    let current = app.current_part().map(|(id, _)| id);
    let loaded = |level: usize| {
        app.frame
            .loaded
            .iter()
            .find(|(k, _)| current.map(|id| (id, level)) == Some(*k))
            .map_or(0, |(_, n)| *n)
    };
    let shown = app.frame.levels;
    let mut rows = overview_rows(app);
    let own: Vec<Row> = app
        .current_part()
        .map(|(_, p)| {
            p.levels
                .iter()
                .map(|l| {
                    let tiles = l.tiles.len();
                    let n = loaded(l.index);
                    let state = if n == 0 {
                        "-".to_string()
                    } else if n >= tiles {
                        "loaded".to_string()
                    } else {
                        format!("{n}/{tiles} tiles")
                    };
                    let row = Row::new(vec![
                        Cell::from(l.index.to_string()),
                        Cell::from(format!("{}×{}", l.width, l.height)),
                        Cell::from(l.points.map_or("?".into(), count)),
                        Cell::from(bytes(l.bytes)),
                        Cell::from(compression_name(l.compression)),
                        Cell::from(state),
                    ]);
                    match shown {
                        Some((lo, hi)) if (lo..=hi).contains(&l.index) => {
                            row.style(Style::new().fg(Color::Green))
                        }
                        _ => row,
                    }
                })
                .collect()
        })
        .unwrap_or_default();
    rows.extend(own);
    let t = Table::new(
        rows,
        [
            Constraint::Length(5),
            Constraint::Length(11),
            Constraint::Length(11),
            Constraint::Length(10),
            Constraint::Length(8),
            Constraint::Fill(1),
        ],
    )
    .header(header(&[
        "level", "size", "points", "bytes", "codec", "cache",
    ]))
    .block(
        Block::bordered().title(title(if app.dataset.has_overview() {
            format!(" overview + levels of part {} ", app.part + 1)
        } else {
            format!(" levels of part {} ", app.part + 1)
        })),
    );
    f.render_widget(t, area);
}

/// One row per overview layer, the root's first: `O` and its layer, the nodes,
/// the points a view of the layer draws, bytes, and how many nodes are loaded.
fn overview_rows(app: &App) -> Vec<Row<'static>> {
    let ds = &app.dataset;
    if !ds.has_overview() {
        return Vec::new();
    }
    // The nodes drawn, by layer (a node's layer from its page, loaded since
    // it was drawn).
    let mut drawn: Vec<(u32, usize)> = app
        .frame
        .loaded
        .iter()
        .filter(|((p, _), n)| *n > 0 && ds.is_overview(*p))
        .filter_map(|((p, _), _)| Some((ds.node(*p)?.layer, *p)))
        .collect();
    drawn.sort_unstable();
    drawn.dedup();
    (1..=ds.layer_count())
        .rev()
        .map(|layer| {
            let s = ds.layer_summary(layer);
            let mine: Vec<usize> = drawn
                .iter()
                .filter(|(l, _)| *l == layer)
                .map(|&(_, id)| id)
                .collect();
            let loaded = mine.len();
            let state = match loaded {
                0 => "-".to_string(),
                n if n == s.nodes => "loaded".to_string(),
                n => format!("{n}/{} nodes", s.nodes),
            };
            let codec = mine
                .first()
                .copied()
                .or(ds.root())
                .and_then(|id| ds.part(id))
                .map_or(1, |p| p.levels[0].compression);
            let row = Row::new(vec![
                Cell::from(format!("O{layer}")),
                Cell::from(format!(
                    "{} node{}",
                    s.nodes,
                    if s.nodes == 1 { "" } else { "s" }
                )),
                Cell::from(count(s.points)),
                Cell::from(bytes(s.bytes)),
                Cell::from(compression_name(codec)),
                Cell::from(state),
            ]);
            if app.frame.overview_tiles > 0 && loaded > 0 {
                row.style(Style::new().fg(Color::Cyan))
            } else {
                row
            }
        })
        .collect()
}

fn draw_memory(f: &mut Frame, app: &App, area: Rect) {
    let budget = match app.frame.budget {
        0 => app.settings.budget,
        b => b,
    };
    let block = Block::bordered().title(title(" memory "));
    let inner = block.inner(area);
    f.render_widget(block, area);
    let [cache, points] =
        Layout::vertical([Constraint::Length(1), Constraint::Length(1)]).areas(inner);
    let s = &app.settings;
    let ratio = |a: u64, b: u64| (a as f64 / b.max(1) as f64).clamp(0.0, 1.0);
    f.render_widget(
        Gauge::default()
            .gauge_style(Style::new().fg(Color::Blue))
            .ratio(ratio(app.frame.cache_bytes, s.memory))
            .label(format!(
                "cache {} / {}",
                bytes(app.frame.cache_bytes),
                bytes(s.memory)
            )),
        cache,
    );
    f.render_widget(
        Gauge::default()
            .gauge_style(Style::new().fg(Color::Magenta))
            .ratio(ratio(app.frame.points, budget))
            .label(format!(
                "points {} / {}",
                count(app.frame.points),
                count(budget)
            )),
        points,
    );
}

fn draw_help(f: &mut Frame, area: Rect) {
    let w = 76.min(area.width);
    let h = (HELP.len() as u16 + 2).min(area.height);
    let r = Rect::new(
        area.x + (area.width - w) / 2,
        area.y + (area.height - h) / 2,
        w,
        h,
    );
    let rows: Vec<Row> = HELP
        .iter()
        .map(|(k, what)| Row::new(vec![Cell::from(k.bold()), Cell::from(*what)]))
        .collect();
    f.render_widget(Clear, r);
    f.render_widget(
        Table::new(rows, [Constraint::Length(24), Constraint::Fill(1)])
            .block(Block::bordered().title(title(" keys (? closes) "))),
        r,
    );
}
