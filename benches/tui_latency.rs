//! Key press → new frame in the inspector, per image protocol, without a terminal:
//! a synthetic dataset, the inspector's render worker at the default point budget,
//! and a 120×40-cell view pane drawn through ratatui's crossterm backend into a
//! byte counter (what would reach the terminal).
//!
//! ```sh
//! cargo run --release --example tui_latency -- [POINTS] [PRESSES] [auto|cpu|gpu]
//! ```
//!
//! Each press orbits the camera by one step (the `→` key), sends the request, waits
//! for the frame that answers it with every tile loaded, and draws it. Reports
//! medians per protocol, for full frames (at rest) and for the reduced frames sent
//! while the camera moves (1/2 of the pixels each way): key → frame drawn, the
//! worker's select/render/encode times, and the bytes sent. Then the sixel
//! choices for moving frames (colours, enlarged half-resolution frames). (The
//! comparison with icy_sixel, through ratatui-image, is in bench/history/: that
//! crate is no longer a dependency.)

use pcimg::camera::Camera;
use pcimg::render::RendererChoice;
use pcimg::store::{self, Dataset, WriteOptions};
use pcimg::tui::app::{App, Settings};
use pcimg::tui::keys::Command;
use pcimg::tui::protocol::{Encoding, Graphics};
use pcimg::tui::worker::{FrameReady, RenderWorker, Report, Request, WorkerOptions};
use ratatui::Terminal;
use ratatui::backend::CrosstermBackend;
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Counts the bytes written and drops them.
struct Counter(Arc<AtomicU64>);

impl Write for Counter {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.fetch_add(b.len() as u64, Ordering::Relaxed);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn wait_complete(w: &RenderWorker, seq: u64) -> Box<FrameReady> {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        assert!(Instant::now() < deadline, "no frame in 120 s");
        match w.recv_timeout(Duration::from_millis(500)) {
            Some(Report::Frame(f)) if f.seq == seq && f.status.pending == 0 => return f,
            Some(Report::Error(e)) => panic!("worker: {e}"),
            _ => {}
        }
    }
}

fn main() -> anyhow::Result<()> {
    // SAFETY: before any thread starts.
    unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    let mut args = std::env::args().skip(1);
    let points: u64 = args.next().map_or(Ok(4_000_000), |s| s.parse())?;
    let presses: usize = args.next().map_or(Ok(15), |s| s.parse())?;
    let renderer: RendererChoice = args
        .next()
        .map_or(Ok(RendererChoice::Auto), |s| s.parse())?;
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("scene.tif");
    let t = Instant::now();
    store::write_part(
        &path,
        &pcimg::synth::scene(points, 1),
        &WriteOptions::default(),
    )?;
    eprintln!(
        "{points} points written in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let ds = Arc::new(Dataset::open(&path)?);
    let cells = (120u16, 40u16);

    println!(
        "| protocol | frame | key → frame drawn ms | select ms | render ms | encode ms | bytes / frame | bytes, same frame again | points drawn | renderer |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut last_sixel = None;
    let runs = [
        (Graphics::Halfblocks, 1),
        (Graphics::Sixel, 1),
        (Graphics::Sixel, 2),
        (Graphics::Kitty, 1),
        (Graphics::Kitty, 2),
        (Graphics::Iterm2, 1),
        (Graphics::Iterm2, 2),
    ];
    for (graphics, scale) in runs {
        let cell_pixels = if graphics == Graphics::Halfblocks {
            (1, 2)
        } else {
            (10, 20)
        };
        let w = RenderWorker::spawn(
            ds.clone(),
            WorkerOptions {
                encoding: Encoding::new(graphics),
                extra_bands: Vec::new(),
                renderer,
                memory: 2 << 30,
                load_threads: 2,
            },
        );
        let mut app = App::new(ds.clone(), Camera::fit(&ds.bounds()), Settings::default());
        let bytes = Arc::new(AtomicU64::new(0));
        // A fixed viewport: there is no real terminal to ask for its size.
        let mut term = Terminal::with_options(
            CrosstermBackend::new(Counter(bytes.clone())),
            ratatui::TerminalOptions {
                viewport: ratatui::Viewport::Fixed(ratatui::layout::Rect::new(
                    0, 0, cells.0, cells.1,
                )),
            },
        )?;
        let request = |app: &App, seq| Request {
            seq,
            camera: app.camera,
            settings: app.settings.clone(),
            cursor: None,
            pick: false,
            cells,
            cell_pixels,
            scale,
            allowance: None,
            pixel_marks: None,
        };
        // Warm up: load the tiles of the first view.
        w.request(request(&app, 0));
        wait_complete(&w, 0);
        let (mut lat, mut sel, mut ren, mut enc, mut sent, mut pts) =
            (vec![], vec![], vec![], vec![], vec![], vec![]);
        let mut again = vec![];
        let mut renderer = String::new();
        for seq in 1..=presses as u64 {
            let t0 = Instant::now();
            app.apply(Command::Orbit(1, 0));
            w.request(request(&app, seq));
            let f = wait_complete(&w, seq);
            let before = bytes.load(Ordering::Relaxed);
            term.draw(|fr| {
                fr.render_widget(&f.image, fr.area());
            })?;
            lat.push(t0.elapsed().as_secs_f64() * 1e3);
            sent.push((bytes.load(Ordering::Relaxed) - before) as f64);
            // A redraw with nothing new (a status line tick): ratatui's diff sends
            // only changed cells, so the image is not sent again.
            let before = bytes.load(Ordering::Relaxed);
            term.draw(|fr| {
                fr.render_widget(&f.image, fr.area());
            })?;
            again.push((bytes.load(Ordering::Relaxed) - before) as f64);
            sel.push(f.status.select_ms);
            ren.push(f.status.render_ms);
            enc.push(f.status.encode_ms);
            pts.push(f.status.points as f64);
            renderer = f.status.renderer.clone();
            if graphics == Graphics::Sixel && scale == 1 {
                last_sixel = Some(f.frame.clone());
            }
        }
        println!(
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} K | {:.0} B | {:.0} | {} |",
            graphics.name(),
            if scale == 1 {
                "full".to_string()
            } else {
                format!("moving, 1/{scale}")
            },
            median(lat),
            median(sel),
            median(ren),
            median(enc),
            median(sent) / 1024.0,
            median(again),
            median(pts),
            renderer
        );
    }
    if let Some(frame) = &last_sixel {
        // Sixel cannot be scaled by the terminal: what a moving frame could be.
        println!("\n| sixel frame | colours | bytes |\n|---|---|---|");
        let half = half_size(frame);
        let enlarged = enlarge(&half, frame.width, frame.height);
        for (what, rgba) in [
            ("full resolution", &frame.rgba),
            ("half resolution, enlarged 2×", &enlarged),
        ] {
            for colors in [32, 16, 8] {
                let ix = pcimg::term::palette::reduce(rgba, colors);
                let s = pcimg::term::sixel::encode_indexed(
                    &ix,
                    frame.width as usize,
                    frame.height as usize,
                )?;
                println!("| {what} | {colors} | {:.0} K |", s.len() as f64 / 1024.0);
            }
        }
    }
    Ok(())
}

/// Every other pixel each way.
fn half_size(f: &pcimg::render::Frame) -> (u32, u32, Vec<u8>) {
    let (w, h) = (f.width / 2, f.height / 2);
    let mut out = Vec::with_capacity((w * h * 4) as usize);
    for y in 0..h {
        for x in 0..w {
            let i = ((2 * y * f.width + 2 * x) * 4) as usize;
            out.extend_from_slice(&f.rgba[i..i + 4]);
        }
    }
    (w, h, out)
}

/// `half` enlarged to `w` × `h` by repeating pixels.
fn enlarge(half: &(u32, u32, Vec<u8>), w: u32, h: u32) -> Vec<u8> {
    let (hw, hh, px) = half;
    let mut out = Vec::with_capacity((w * h * 4) as usize);
    for y in 0..h {
        let sy = (y * hh / h).min(hh - 1);
        for x in 0..w {
            let sx = (x * hw / w).min(hw - 1);
            let i = ((sy * hw + sx) * 4) as usize;
            out.extend_from_slice(&px[i..i + 4]);
        }
    }
    out
}
