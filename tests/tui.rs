//! The terminal inspector: its panels, keys and sanitizing drawn into ratatui's
//! `TestBackend` (half-blocks, deterministic), a frame from the render worker, sixel
//! frames drawn through ratatui (first cell, sent only when changed, tmux
//! passthrough), and the real binary driven through tmux (start, pin a level, quit,
//! terminal sane; and ending when its terminal closes).

mod common;

use common::tmux::Tmux;

use crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
use pcimg::camera::Camera;
use pcimg::render::RendererChoice;
use pcimg::store::{self, Dataset, WriteOptions};
use pcimg::tui::app::{App, LodChoice, Settings};
use pcimg::tui::keys::command_for;
use pcimg::tui::protocol::{Encoding, Graphics, PaneImage};
use pcimg::tui::ui;
use pcimg::tui::worker::{RenderWorker, Report, Request, WorkerOptions};
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A directory of two parts of the synthetic scene.
fn two_parts(dir: &Path, source: Option<&str>) -> PathBuf {
    let d = dir.join("parts");
    std::fs::create_dir_all(&d).unwrap();
    let opts = WriteOptions {
        source: source.map(String::from),
        ..Default::default()
    };
    store::write_part(
        &d.join("a_north.tif"),
        &pcimg::synth::scene(300_000, 1),
        &opts,
    )
    .unwrap();
    store::write_part(
        &d.join("b_south.tif"),
        &pcimg::synth::scene(70_000, 2),
        &opts,
    )
    .unwrap();
    d
}

fn app_for(path: &Path) -> App {
    let ds = Arc::new(Dataset::open(path).unwrap());
    let cam = Camera::fit(&ds.bounds());
    App::new(ds, cam, Settings::default())
}

/// The screen as lines of text.
fn screen(app: &App, image: Option<&PaneImage>) -> Vec<String> {
    let mut t = Terminal::new(TestBackend::new(160, 48)).unwrap();
    t.draw(|f| ui::draw(f, app, image)).unwrap();
    let buf = t.backend().buffer().clone();
    let w = buf.area.width as usize;
    buf.content()
        .chunks(w)
        .map(|row| row.iter().map(|c| c.symbol()).collect::<String>())
        .collect()
}

fn press(app: &mut App, code: KeyCode) {
    let cmd = command_for(KeyEvent::new(code, KeyModifiers::NONE)).expect("a mapped key");
    app.apply(cmd);
}

#[test]
fn panels_list_parts_bands_and_levels() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_parts(dir.path(), Some("synthetic scan"));
    let mut app = app_for(&path);
    let text = screen(&app, None).join("\n");
    assert!(
        text.contains("a_north.tif") && text.contains("b_south.tif"),
        "{text}"
    );
    assert!(
        text.contains("300,000") && text.contains("70,000"),
        "{text}"
    );
    assert!(text.contains("source synthetic scan"), "{text}");
    // The selected part's bounds in full, the others' extents in the table.
    assert!(
        text.contains("bounds x ") && text.contains("extent x×y×z"),
        "{text}"
    );
    for band in &app.dataset.parts().unwrap()[0].bands {
        assert!(
            text.contains(&band.name),
            "band {} missing:\n{text}",
            band.name
        );
    }
    assert!(text.contains("intensity"));
    // Every level of the selected part, with its raster size.
    let levels = &app.dataset.parts().unwrap()[0].levels;
    assert!(levels.len() >= 3);
    for l in levels {
        assert!(
            text.contains(&format!("{}×{}", l.width, l.height)),
            "level {} missing:\n{text}",
            l.index
        );
    }
    assert!(text.contains("levels of part 1"));
    assert!(text.contains("cache 0 B / 2.0 GiB"), "{text}");

    // Tab selects the next part: its levels replace the first part's.
    press(&mut app, KeyCode::Tab);
    let text = screen(&app, None).join("\n");
    assert!(text.contains("levels of part 2"), "{text}");
    let l0 = &app.dataset.parts().unwrap()[1].levels[0];
    assert!(text.contains(&format!("{}×{}", l0.width, l0.height)));
}

#[test]
fn the_parts_list_scrolls_to_the_selected_part() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("many");
    std::fs::create_dir_all(&d).unwrap();
    for i in 0..12 {
        let pts = pcimg::synth::scene(3_000, i + 1);
        let path = d.join(format!("part-{i:02}.tif"));
        store::write_part(&path, &pts, &WriteOptions::default()).unwrap();
    }
    let mut app = app_for(&d);
    let text = screen(&app, None).join("\n");
    assert!(
        text.contains("part-00.tif") && text.contains("parts (1/12)"),
        "{text}"
    );
    assert!(
        !text.contains("part-11.tif"),
        "12 parts cannot all fit:\n{text}"
    );
    for _ in 0..11 {
        press(&mut app, KeyCode::Tab);
    }
    let text = screen(&app, None).join("\n");
    assert!(text.contains("parts (12/12)"), "{text}");
    assert!(
        text.contains("part-11.tif"),
        "the selected part is off screen:\n{text}"
    );
}

#[test]
fn keys_pin_levels_and_cycle_colours_in_the_status_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_parts(dir.path(), None);
    let mut app = app_for(&path);
    let status = |app: &App| screen(app, None)[46].clone();
    assert!(
        status(&app).contains("auto (view-dependent)"),
        "{}",
        status(&app)
    );
    assert!(status(&app).contains("| rgb |"));

    press(&mut app, KeyCode::Char('2'));
    assert_eq!(app.settings.lod, LodChoice::Pinned(2));
    assert!(status(&app).contains("pinned level 2"), "{}", status(&app));
    press(&mut app, KeyCode::Char(']'));
    assert!(status(&app).contains("pinned level 1"), "finer");
    press(&mut app, KeyCode::Char('['));
    press(&mut app, KeyCode::Char('['));
    assert!(
        status(&app).contains("pinned level 2"),
        "coarsest of 3 levels"
    );
    press(&mut app, KeyCode::Char('c'));
    assert!(status(&app).contains("| intensity |"), "{}", status(&app));
    press(&mut app, KeyCode::Char('c'));
    assert!(status(&app).contains("| height |"));
    press(&mut app, KeyCode::Char('m'));
    assert!(status(&app).contains("auto (distance rule)"));
    press(&mut app, KeyCode::Char('a'));
    assert!(status(&app).contains("auto (view-dependent)"));
    press(&mut app, KeyCode::Char('b'));
    assert!(status(&app).contains("/ 8,000,000"), "{}", status(&app));

    press(&mut app, KeyCode::Char('?'));
    let text = screen(&app, None).join("\n");
    assert!(text.contains("keys (? closes)") && text.contains("pin a pyramid level"));
}

#[test]
fn control_characters_from_metadata_are_sanitized() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("evil.tif");
    let opts = WriteOptions {
        source: Some("scan\x1b[31mRED\x1b]0;title\x07".into()),
        crs: Some("EPSG:\u{9b}2J4326".into()),
        ..Default::default()
    };
    store::write_part(&path, &pcimg::synth::scene(5_000, 4), &opts).unwrap();
    let mut app = app_for(&path);
    app.message = "worker said \x1b[2J".into();
    let lines = screen(&app, None);
    let text = lines.join("\n");
    assert!(
        !text.chars().any(|c| c.is_control() && c != '\n'),
        "control characters reached the screen:\n{text:?}"
    );
    assert!(text.contains("scan\u{FFFD}[31mRED"), "{text}");
    assert!(text.contains("EPSG:\u{FFFD}2J4326"), "{text}");
    assert!(text.contains("worker said \u{FFFD}[2J"), "{text}");
}

#[test]
fn the_worker_renders_and_encodes_half_block_frames() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_parts(dir.path(), None);
    let mut app = app_for(&path);
    let w = common::halfblock_worker(app.dataset.clone());
    app.settings.lod = LodChoice::Pinned(1);
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    w.request(frame_request(&app, area, 1));
    let frame = complete_frame(&w, 1);
    assert_eq!(frame.seq, 1);
    assert_eq!(frame.cells, (area.width, area.height));
    assert_eq!(frame.status.levels, Some((1, 1)));
    let expected: u64 = app
        .dataset
        .parts()
        .unwrap()
        .into_iter()
        .map(|p| p.levels[1].points.unwrap())
        .sum();
    assert_eq!(
        frame.status.points, expected,
        "level 1 of both parts, all in view"
    );
    assert!(frame.status.renderer.starts_with("cpu"));
    assert_eq!(frame.frame.width as u16, area.width);
    app.frame = frame.status.clone();
    let lines = screen(&app, Some(&frame.image));
    let pane: String = lines[area.y as usize..(area.y + area.height) as usize]
        .iter()
        .map(|l| {
            l.chars()
                .skip(area.x as usize)
                .take(area.width as usize)
                .collect::<String>()
        })
        .collect();
    assert!(
        pane.contains('▀') || pane.contains('▄'),
        "no half-blocks in the view"
    );
    let text = lines.join("\n");
    assert!(
        text.contains("loaded"),
        "levels panel shows what is cached:\n{text}"
    );
}

/// A request for a full frame of `app`'s view in `area` (half-block cells).
fn frame_request(app: &App, area: ratatui::layout::Rect, seq: u64) -> Request {
    Request {
        seq,
        camera: app.camera,
        settings: app.settings.clone(),
        cursor: None,
        pick: false,
        cells: (area.width, area.height),
        cell_pixels: (1, 2),
        scale: 1,
        allowance: None,
        pixel_marks: None,
    }
}

/// The worker's first complete frame (no tile pending) answering request
/// `seq`; fails the test on a worker error or after 30 s.
fn complete_frame(w: &RenderWorker, seq: u64) -> Box<pcimg::tui::worker::FrameReady> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no complete frame in 30 s");
        match w.recv_timeout(Duration::from_millis(200)) {
            Some(Report::Frame(f)) if f.status.pending == 0 && f.seq == seq => break f,
            Some(Report::Error(e)) => panic!("worker error: {e}"),
            _ => {}
        }
    }
}

/// Colouring through a ramp, the legend shows the drawn points' values under
/// the ramp's colours: a histogram of the frame's tiles over the legend's
/// range, a bar a ramp cell, as the panel's line below the colours.
#[test]
fn the_legend_draws_a_histogram_of_the_coloured_band_under_its_ramp() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_parts(dir.path(), None);
    let mut app = app_for(&path);
    app.settings.style.mode = pcimg::render::ColorMode::Height;
    let w = common::halfblock_worker(app.dataset.clone());
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    w.request(frame_request(&app, area, 1));
    let frame = complete_frame(&w, 1);
    let h = &frame.status.histogram;
    assert_eq!(h.len(), 24, "{h:?}");
    let counted: u64 = h.iter().map(|&c| c as u64).sum();
    // Heights span the legend's range (2nd to 98th percentile of the drawn
    // points, or the bounds): most points fall in it, none twice.
    assert!(
        counted > 0 && counted <= frame.status.points,
        "{counted} of {}",
        frame.status.points
    );
    app.frame = frame.status.clone();
    let lines = pcimg::tui::panels::lines(&app);
    let text: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    let bar = text
        .iter()
        .position(|l| l.chars().count() == 24 && l.chars().all(|c| c == '█'));
    let bar = bar.unwrap_or_else(|| panic!("no ramp bar in {text:#?}"));
    let spark = &text[bar + 1];
    assert!(
        spark.chars().any(|c| "▁▂▃▄▅▆▇".contains(c)) && spark.chars().count() == 24,
        "{text:#?}"
    );
    // Not colouring through a ramp: no histogram.
    app.settings.style.mode = pcimg::render::ColorMode::Rgb;
    w.request(frame_request(&app, area, 2));
    assert!(complete_frame(&w, 2).status.histogram.is_empty());
}

/// Where a cell written over the image would take it away (tmux drawing sixel
/// itself), the worker draws the scale bar, the crosshair and the picks into
/// the frame's pixels and the view has no overlay cells; elsewhere the frame
/// carries none of them and the cells do.
#[test]
fn overlays_go_into_the_pixels_where_cells_would_erase_the_image() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_parts(dir.path(), None);
    let mut app = app_for(&path);
    let w = common::halfblock_worker(app.dataset.clone());
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    let centre = app.dataset.bounds().center();
    let request = |seq: u64, pixel_marks| Request {
        cursor: Some((0.25, 0.5)),
        pixel_marks,
        ..frame_request(&app, area, seq)
    };
    let frame = |seq| complete_frame(&w, seq);
    w.request(request(1, None));
    let plain = frame(1);
    w.request(request(2, Some((vec![centre], "m".to_string()))));
    let marked = frame(2);
    assert!(!request(1, None).same_frame(&request(2, Some((vec![], "m".into())))));
    // The same points, with the overlays' pixels over them.
    let (a, b) = (&plain.frame, &marked.frame);
    assert_eq!((a.width, a.height), (b.width, b.height));
    let differ = a
        .rgba
        .chunks_exact(4)
        .zip(b.rgba.chunks_exact(4))
        .filter(|(p, q)| p != q)
        .count();
    assert!(differ > 20, "{differ} pixels differ");
    // No overlay cells where they are in the pixels; some where they are not.
    app.picking = true;
    app.frame = marked.status.clone();
    app.overlays_in_pixels = true;
    let none = pcimg::tui::overlay::of_app(&app, area, &marked.image);
    assert!(none.is_empty(), "{none:?}");
    app.overlays_in_pixels = false;
    assert!(!pcimg::tui::overlay::of_app(&app, area, &marked.image).is_empty());
}

/// Bytes written by ratatui's crossterm backend, kept for the test to read.
#[derive(Clone, Default)]
struct Sink(Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for Sink {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Sink {
    fn take(&self) -> String {
        String::from_utf8(std::mem::take(&mut *self.0.lock().unwrap())).unwrap()
    }
}

#[test]
fn sixel_frames_go_into_the_first_cell_and_are_sent_only_when_they_change() {
    use pcimg::tui::protocol;
    use ratatui::backend::CrosstermBackend;
    use ratatui::layout::Rect;
    // 6×3 cells of 10×20 px: a red square on black.
    let mut frame = pcimg::render::Frame::background(60, 60, [0, 0, 0]);
    for y in 10..30 {
        for x in 20..40 {
            frame.rgba[(y * 60 + x) * 4] = 255;
        }
    }
    let sixel = Encoding::new(Graphics::Sixel);
    let image = protocol::encode(sixel, &frame, (6, 3), (60, 60)).unwrap();
    let pane = Rect::new(2, 1, 6, 3);

    // In ratatui's buffer: the escape string in the first cell, the rest skipped.
    let mut t = Terminal::new(TestBackend::new(12, 6)).unwrap();
    let buf = t
        .draw(|f| f.render_widget(&image, pane))
        .unwrap()
        .buffer
        .clone();
    let first = buf[(2, 1)].symbol();
    assert!(
        first.starts_with("\x1b[6X\x1b[1B"),
        "pane erased first: {first:?}"
    );
    assert!(first.contains("\x1bP0;1;0q\"1;1;60;60#"), "{first:?}");
    assert!(first.ends_with("\x1b\\"));
    let skipped = |x, y| buf[(x, y)].diff_option == ratatui::buffer::CellDiffOption::Skip;
    assert!(skipped(3, 1) && skipped(7, 3) && !skipped(8, 3) && !skipped(2, 1));

    // Through the crossterm backend: sent once, not again while it is unchanged.
    let sink = Sink::default();
    let mut t = Terminal::with_options(
        CrosstermBackend::new(sink.clone()),
        ratatui::TerminalOptions {
            viewport: ratatui::Viewport::Fixed(Rect::new(0, 0, 12, 6)),
        },
    )
    .unwrap();
    let draw = |t: &mut Terminal<CrosstermBackend<Sink>>, img: &PaneImage, note: &str| {
        t.draw(|f| {
            f.render_widget(img, pane);
            f.render_widget(
                ratatui::widgets::Paragraph::new(note.to_string()),
                Rect::new(0, 5, 12, 1),
            );
        })
        .unwrap();
    };
    draw(&mut t, &image, "one");
    let sent = sink.take();
    assert_eq!(sent.matches("\x1bP0;1;0q").count(), 1, "{sent:?}");
    draw(&mut t, &image, "two");
    let sent = sink.take();
    assert!(!sent.contains("\x1bP") && sent.contains("two"), "{sent:?}");
    // A changed frame is sent again.
    frame.rgba[0] = 255;
    let changed = protocol::encode(sixel, &frame, (6, 3), (60, 60)).unwrap();
    draw(&mut t, &changed, "two");
    assert_eq!(sink.take().matches("\x1bP0;1;0q").count(), 1);

    // In tmux the whole string goes through passthrough, every inner ESC doubled.
    let through = Encoding {
        passthrough: true,
        ..sixel
    };
    let tmux = protocol::encode(through, &frame, (6, 3), (60, 60)).unwrap();
    let mut t = Terminal::new(TestBackend::new(12, 6)).unwrap();
    t.draw(|f| f.render_widget(&tmux, pane)).unwrap();
    let s = t.backend().buffer()[(2, 1)].symbol().to_string();
    assert!(s.starts_with("\x1bPtmux;\x1b\x1b[6X"), "{s:?}");
    assert!(s.ends_with("\x1b\x1b\\\x1b\\"), "{s:?}");
    assert_eq!(s.matches('\x1b').count() % 2, 0);
}

/// A synthetic part of `n` points written in `dir`.
fn scan_part(dir: &Path, n: u64, seed: u64) -> PathBuf {
    let path = dir.join("scan.tif");
    store::write_part(
        &path,
        &pcimg::synth::scene(n, seed),
        &WriteOptions::default(),
    )
    .unwrap();
    path
}

#[test]
fn the_binary_runs_in_tmux_and_restores_the_terminal() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = scan_part(dir.path(), 70_000, 5);
    let tmux = Tmux::new("test");
    // The status and terminal modes are asked for after it ends (a list typed on
    // one line would go on while the inspector is stopped by Ctrl-Z).
    tmux.inspect((150, 45), &path, "");
    tmux.wait_for("the panels", 10, |s| {
        s.contains("levels of part 1")
            && s.contains("view · text")
            && (s.contains("fps") || s.contains("idle"))
    });
    tmux.run(&["send-keys", "-t", "t", "1"]);
    tmux.wait_for("the status line to show the pinned level", 5, |s| {
        s.contains("pinned level 1 | level 1 |")
    });
    // Ctrl-Z hands the terminal back to the shell; fg brings the inspector back.
    tmux.run(&["send-keys", "-t", "t", "C-z"]);
    tmux.wait_for("the shell after Ctrl-Z", 5, |s| {
        !s.contains("levels of part 1") && s.to_lowercase().contains("stopped")
    });
    tmux.run(&["send-keys", "-t", "t", "-l", "fg"]);
    tmux.run(&["send-keys", "-t", "t", "Enter"]);
    tmux.wait_for("the inspector after fg", 5, |s| {
        s.contains("pinned level 1 | level 1 |") && s.contains('▀')
    });
    // A smaller window: the panels and the frame follow.
    tmux.run(&["resize-window", "-t", "t", "-x", "100", "-y", "30"]);
    tmux.wait_for("a frame at the new size", 5, |s| {
        let rows: Vec<&str> = s.lines().collect();
        rows.len() >= 29
            && rows[0].chars().count() == 100
            && rows[0].contains("view")
            && s.contains('▀')
    });
    tmux.run(&["send-keys", "-t", "t", "q"]);
    tmux.wait_for("the prompt", 5, |s| !s.contains("levels of part 1"));
    tmux.run(&["send-keys", "-t", "t", "-l", "echo EXIT=$?; stty -a"]);
    tmux.run(&["send-keys", "-t", "t", "Enter"]);
    let s = tmux.wait_for("the shell", 5, |s| {
        s.contains("EXIT=") && s.contains("icanon")
    });
    assert!(s.contains("EXIT=0"), "{s}");
    let words: Vec<&str> = s.split_whitespace().collect();
    assert!(words.contains(&"icanon") && words.contains(&"echo"), "{s}");
    assert!(
        !words.contains(&"-icanon") && !words.contains(&"-echo"),
        "{s}"
    );
    assert!(
        !s.contains("levels of part 1"),
        "the alternate screen is left: {s}"
    );
}

#[test]
fn the_worker_picks_the_point_under_the_crosshair() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.tif");
    store::write_part(
        &path,
        &pcimg::synth::scene_classified(80_000, 3),
        &WriteOptions::default(),
    )
    .unwrap();
    let mut app = app_for(&path);
    let w = RenderWorker::spawn(
        app.dataset.clone(),
        WorkerOptions {
            extra_bands: vec!["classification".into()],
            encoding: Encoding::new(Graphics::Halfblocks),
            renderer: RendererChoice::Cpu,
            memory: 1 << 30,
            load_threads: 2,
        },
    );
    app.settings.style.mode = pcimg::render::ColorMode::Classification;
    // Straight down at the centre of the scene: the crosshair's point is there.
    app.camera.pitch = -89.0f64.to_radians();
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    let (camera, settings) = (app.camera, app.settings.clone());
    let pick_at = |w: &RenderWorker, seq: u64, cursor: (f64, f64)| {
        w.request(Request {
            seq,
            camera,
            settings: settings.clone(),
            cursor: Some(cursor),
            pick: true,
            cells: (area.width, area.height),
            cell_pixels: (4, 8),
            scale: 1,
            allowance: None,
            pixel_marks: None,
        });
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            assert!(Instant::now() < deadline, "no pick in 30 s");
            // In a new frame, or over the frame drawn last (no new frame).
            match w.recv_timeout(Duration::from_millis(200)) {
                Some(Report::Frame(f)) if f.seq == seq && f.pick.is_some() => {
                    break (f.pick.clone().unwrap(), Some(f.status.clone()));
                }
                Some(Report::Pick(p)) => break (p, None),
                Some(Report::Error(e)) => panic!("worker error: {e}"),
                _ => {}
            }
        }
    };
    let (p, status) = pick_at(&w, 1, (0.5, 0.5));
    let p = p.expect("a point under the crosshair");
    let c = app.dataset.bounds().center();
    // Within a few pixels of the centre: the scene is 400 m across the view.
    assert!(
        (p.position[0] - c[0]).abs() < 10.0 && (p.position[1] - c[1]).abs() < 10.0,
        "{p:?}"
    );
    let names: Vec<&str> = p.attributes.iter().map(|a| a.0.as_str()).collect();
    assert_eq!(names, ["intensity", "classification"]);
    // The panel lists it, with the class's name.
    app.add_pick(Some(p));
    app.frame = status.expect("the first pick draws the first frame");
    let text = screen(&app, None).join("\n");
    assert!(text.contains("A 637"), "{text}");
    assert!(text.contains("classification"), "{text}");
    assert!(text.contains("ground") || text.contains("building") || text.contains("vegetation"));
    // A second pick: the distances.
    let (g, status) = pick_at(&w, 2, (0.25, 0.5));
    assert!(status.is_none(), "picked over the frame drawn");
    app.add_pick(g);
    let text = screen(&app, None).join("\n");
    assert!(text.contains("A→B 3D"), "{text}");
}

#[test]
fn a_pick_over_the_shown_frame_draws_no_new_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = scan_part(dir.path(), 60_000, 7);
    let mut app = app_for(&path);
    let w = common::halfblock_worker(app.dataset.clone());
    app.camera.pitch = -89.0f64.to_radians();
    let request = |seq: u64, pick: bool, camera: Camera| Request {
        seq,
        camera,
        settings: app.settings.clone(),
        cursor: Some((0.5, 0.5)),
        pick,
        cells: (100, 40),
        cell_pixels: (2, 4),
        scale: 1,
        allowance: None,
        pixel_marks: None,
    };
    let next = |w: &RenderWorker| match w.recv_timeout(Duration::from_secs(30)) {
        Some(Report::Error(e)) => panic!("worker error: {e}"),
        Some(r) => r,
        None => panic!("nothing from the worker in 30 s"),
    };
    w.request(request(1, false, app.camera));
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        assert!(Instant::now() < deadline, "no complete frame in 30 s");
        if let Report::Frame(f) = next(&w)
            && f.status.pending == 0
        {
            let view = f.status.view.expect("the frame says how it was drawn");
            assert_eq!((view.width, view.height), (200, 160));
            assert_eq!(view.camera, app.camera);
            break;
        }
    }
    // The same picture with a pick: answered with the point, no frame drawn.
    w.request(request(2, true, app.camera));
    let picked = match next(&w) {
        Report::Pick(Some(p)) => p,
        Report::Pick(None) => panic!("no point under the crosshair at the centre"),
        _ => panic!("a frame was drawn for a pick over the shown one"),
    };
    let c = app.dataset.bounds().center();
    assert!(
        (picked.position[0] - c[0]).abs() < 10.0 && (picked.position[1] - c[1]).abs() < 10.0,
        "{picked:?}"
    );
    // The same point as a pick drawn with a frame (the rasterizer's id buffer):
    // a setting that changes nothing drawn makes it draw one.
    let mut again = request(3, true, app.camera);
    again.settings.memory += 1;
    w.request(again);
    match next(&w) {
        Report::Frame(f) => {
            let p = f.pick.flatten().expect("the same point");
            assert_eq!(p.position, picked.position);
        }
        _ => panic!("a new request draws a frame"),
    }
    // A camera that moved: a frame (with the pick in it) is the next report.
    let mut moved = app.camera;
    moved.zoom(0.8);
    w.request(request(4, true, moved));
    match next(&w) {
        Report::Frame(f) => assert!(f.seq == 4 && f.pick.is_some()),
        _ => panic!("a new camera draws a frame"),
    }
}

#[test]
fn the_scale_bar_is_one_row_of_text_in_the_datasets_unit_in_tmux() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("utm.tif");
    let utm = r#"PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",UNIT["degree",0.0174532925199433]],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
    let opts = WriteOptions {
        crs: Some(utm.into()),
        ..Default::default()
    };
    store::write_part(&path, &pcimg::synth::scene(40_000, 8), &opts).unwrap();
    let tmux = Tmux::new("scalebar");
    tmux.inspect((140, 42), &path, "--protocol text");
    // The bar (`├──┤`) on the view's last row, its label on the row above.
    let s = tmux.wait_for("the scale bar", 15, |s| {
        s.lines().any(|l| l.contains('├') && l.contains('┤')) && s.contains("view · text")
    });
    let rows: Vec<Vec<char>> = s.lines().map(|l| l.chars().collect()).collect();
    let bar_row = rows
        .iter()
        .position(|r| r.contains(&'├') && r.contains(&'┤'))
        .unwrap();
    let x = rows[bar_row].iter().position(|&c| c == '├').unwrap();
    let end = rows[bar_row].iter().position(|&c| c == '┤').unwrap();
    assert!(rows[bar_row][x + 1..end].iter().all(|&c| c == '─'), "{s}");
    let above: String = rows[bar_row - 1][x..].iter().collect();
    let number: String = above
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect();
    let unit: String = above[number.len()..]
        .strip_prefix(' ')
        .unwrap_or("")
        .chars()
        .take_while(|c| c.is_alphabetic())
        .collect();
    assert!(number.parse::<f64>().is_ok(), "{s}");
    assert_eq!(unit, "m", "metres as m, not M:\n{s}");
    // One row: the label appears once in the view, and nothing of it above.
    let label = format!("{number} m");
    let in_view = rows
        .iter()
        .filter(|r| r.len() > x && r[x..].iter().collect::<String>().contains(&label))
        .count();
    assert_eq!(in_view, 1, "{s}");
    let two_up: String = rows[bar_row - 2][x..].iter().take(label.len()).collect();
    assert!(!two_up.contains(&number), "{s}");
    // The panel states the scale in the same unit.
    assert!(s.contains(" m at the centre"), "{s}");
    tmux.run(&["send-keys", "-t", "t", "q"]);
    tmux.wait_for("the prompt", 5, |s| !s.contains("view · text"));
}

#[test]
fn the_inspector_shows_class_legend_and_picks_in_tmux() {
    if !common::tool_available("tmux", "-V") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.tif");
    store::write_part(
        &path,
        &pcimg::synth::scene_classified(60_000, 5),
        &WriteOptions::default(),
    )
    .unwrap();
    let tmux = Tmux {
        socket: format!("pcimg-test-legend-{}", std::process::id()),
    };
    tmux.inspect((160, 50), &path, "--color classification");
    tmux.wait_for("the class legend", 10, |s| {
        s.contains("ground") && s.contains("building") && s.contains("high vegetation")
    });
    // Hide the selected class (ground, the first row).
    tmux.run(&["send-keys", "-t", "t", " "]);
    tmux.wait_for("the filter in the status line", 5, |s| {
        s.contains("| filtered")
    });
    tmux.run(&["send-keys", "-t", "t", " "]);
    tmux.wait_for("the filter gone", 5, |s| !s.contains("| filtered"));
    // Pick mode and a pick at the centre.
    tmux.run(&["send-keys", "-t", "t", "x"]);
    tmux.wait_for("pick mode", 5, |s| s.contains("Enter picks"));
    tmux.run(&["send-keys", "-t", "t", "Enter"]);
    let s = tmux.wait_for("the picked point", 10, |s| {
        s.contains("picked ") && s.contains("A 637")
    });
    assert!(s.contains("classification"), "{s}");
    tmux.run(&["send-keys", "-t", "t", "q"]);
    tmux.wait_for("pick mode left", 5, |s| !s.contains("Enter picks"));
    // The mouse (SGR reports, as terminals send them): a click on the legend's
    // ground row hides ground; a click in the view picks the point there.
    let s = tmux.capture();
    let row = s.lines().position(|l| l.contains(" ground ")).unwrap() + 1;
    let click = |col: usize, row: usize| {
        for end in ['M', 'm'] {
            let seq = format!("\x1b[<0;{col};{row}{end}");
            tmux.run(&["send-keys", "-t", "t", "-l", &seq]);
        }
    };
    click(5, row);
    tmux.wait_for("ground hidden by a click", 5, |s| s.contains("| filtered"));
    click(5, row);
    tmux.wait_for("ground shown again", 5, |s| !s.contains("| filtered"));
    tmux.run(&["send-keys", "-t", "t", "X"]);
    tmux.wait_for("the picks forgotten", 5, |s| !s.contains("A 637"));
    click(110, 25);
    tmux.wait_for("a pick by a click in the view", 10, |s| s.contains("A 637"));
    // The click left the crosshair on: the first q leaves pick mode.
    tmux.run(&["send-keys", "-t", "t", "q"]);
    tmux.wait_for("pick mode left", 5, |s| !s.contains("Enter picks"));
    tmux.run(&["send-keys", "-t", "t", "q"]);
    tmux.wait_for("the prompt", 5, |s| !s.contains("high vegetation"));
}

/// Whether a process is alive (not gone, not a zombie), from `/proc`.
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            s.rsplit_once(')')
                .map(|(_, rest)| !rest.trim_start().starts_with('Z'))
        })
        .unwrap_or(false)
}

#[test]
fn the_binary_ends_when_its_terminal_goes_away() {
    if !common::tool_available("tmux", "-V") || !Path::new("/proc/self/stat").exists() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = scan_part(dir.path(), 20_000, 6);
    let tmux = Tmux::new("hup");
    // The inspector is the pane's process itself (no shell in between).
    let command = format!(
        "exec env NODEVICE_SELECT=1 '{}' inspect '{}' --renderer cpu",
        env!("CARGO_BIN_EXE_pcimg"),
        path.display()
    );
    tmux.start(&command);
    tmux.wait_for("the panels", 10, |s| {
        s.contains("levels of part 1") && (s.contains("fps") || s.contains("idle"))
    });
    let pid: u32 = tmux
        .run(&["display", "-p", "-t", "t", "#{pane_pid}"])
        .trim()
        .parse()
        .unwrap();
    assert!(alive(pid));
    // Closing the pane closes the terminal under the inspector (SIGHUP, and reads
    // that return nothing): it must end, not spin.
    tmux.run(&["kill-pane", "-t", "t"]);
    let deadline = Instant::now() + Duration::from_secs(10);
    while alive(pid) {
        if Instant::now() > deadline {
            // Leave no spinning process behind.
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("the inspector still ran 10 s after its terminal closed");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A COPC file in the inspector, with no conversion: the worker draws its
/// octree's nodes, and the panels show the file, its fields and the depths
/// reached with the nodes loaded.
#[test]
fn a_copc_file_is_inspected_from_its_octree() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/autzen_trim.copc.laz");
    let ds = Arc::new(pcimg::copc_tiles::open(&path).unwrap());
    let cam = Camera::fit(&ds.bounds());
    let mut app = App::new(ds, cam, Settings::default());
    let w = common::halfblock_worker(app.dataset.clone());
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    w.request(frame_request(&app, area, 1));
    let frame = complete_frame(&w, 1);
    assert!(frame.status.points >= 9_260, "{:?}", frame.status.points);
    app.frame = frame.status.clone();
    let text = screen(&app, Some(&frame.image)).join("\n");
    for want in [
        "COPC file",
        "autzen_trim.copc.laz",
        "110,000 points",
        "octree",
        "9,260",
        "classification",
        "1/1",
    ] {
        assert!(text.contains(want), "{want} missing:\n{text}");
    }
}

/// A survey of COPC files (`pcimg index` over the four quadrants of
/// autzen_trim) in the inspector: the first frame draws the overview node,
/// no file opened, and the panels say so.
#[test]
fn a_survey_of_copc_files_is_inspected_from_its_overview() {
    let t = tempfile::tempdir().unwrap();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/survey");
    for q in ["q00", "q01", "q10", "q11"] {
        let name = format!("autzen-{q}.copc.laz");
        std::fs::copy(fixtures.join(&name), t.path().join(&name)).unwrap();
    }
    let o = Command::new(env!("CARGO_BIN_EXE_pcimg"))
        .arg("index")
        .arg(t.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ds = Arc::new(pcimg::survey::open(t.path()).unwrap());
    let cam = Camera::fit(&ds.bounds());
    let mut app = App::new(ds, cam, Settings::default());
    app.settings.budget = 40_000;
    let w = common::halfblock_worker(app.dataset.clone());
    let area = ui::areas(ratatui::layout::Rect::new(0, 0, 160, 48), &app).view_inner;
    w.request(frame_request(&app, area, 1));
    let frame = complete_frame(&w, 1);
    assert_eq!(frame.status.points, 27_502, "{:?}", frame.status);
    app.frame = frame.status.clone();
    let text = screen(&app, Some(&frame.image)).join("\n");
    for want in [
        "COPC survey · 0 of 4 files opened",
        "110,000 points",
        "27,502",
        "1/1",
    ] {
        assert!(text.contains(want), "{want} missing:\n{text}");
    }
}
