//! How good a text frame is: our symbol encoder (`pcimg_term::symbols`) next
//! to chafa's on the same frame, the same cell count and the same symbol set.
//!
//! ```text
//! cargo run --release -p pcimg-term --example text_quality -- FRAME.png COLS ROWS \
//!     [--cell 8x16] [--colors full|256|16] [--dither none|ordered|diffusion]
//!     [--no-dither] [--chafa-work N] [--runs N]
//! ```
//! FRAME.png should be COLS·8 × ROWS·16 pixels (the cell size given), so the
//! reference is the frame itself. Each text frame is drawn back to pixels with
//! that cell geometry (a block symbol fills its sub-cells, split as foot and
//! kitty split a cell: sub-cell j of n starts at ⌊j·size/n⌋; a braille dot is a
//! box half its sub-cell's width and height, centred), and compared with the
//! frame by SSIM (Wang et al. 2004: luma, 11×11 Gaussian window, σ 1.5, K1
//! 0.01, K2 0.03, the mean over the picture), and by the colour error from
//! afar ("far": both averaged over squares of a cell's height, the mean RGB
//! distance; banding shows there, dither noise does not). Prints one line a
//! set: SSIM, far and bytes for ours and chafa's, our median encode time,
//! symbols chafa used that we cannot draw back (counted as background).
//! `chafa` must be on PATH. With `CELLS=1` in the environment, each set is
//! followed by where chafa's frame beats ours, cell by cell (`worst_cells`).
//!
//! In 256 and 16 colours ours is `Symbols::of_depth` (fitted in the palette,
//! the error diffused); `--no-dither` takes the 24-bit cells and maps each
//! colour to the nearest palette colour instead (the encoder before #43).
//! `--dither` is passed to chafa (its default is `none`).
use pcimg_term::Rgba;
use pcimg_term::symbols::{Depth, SymbolSet, Symbols, palette256_rgb};
use std::collections::HashMap;
use std::process::Command;
use std::time::Instant;

type Colour = [u8; 3];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!(
            "usage: text_quality FRAME.png COLS ROWS [--cell 8x16] [--colors full|256|16] [--dither none|ordered|diffusion] [--no-dither] [--chafa-work N] [--runs N]"
        );
        std::process::exit(2);
    }
    let (path, cols, rows): (&str, u16, u16) = (&args[0], args[1].parse()?, args[2].parse()?);
    let opt = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let (cw, ch) = match opt("--cell") {
        Some(c) => {
            let (w, h) = c.split_once('x').ok_or("--cell WxH")?;
            (w.parse::<usize>()?, h.parse::<usize>()?)
        }
        None => (8, 16),
    };
    let colors = opt("--colors").unwrap_or_else(|| "full".into());
    let depth = match colors.as_str() {
        "256" => Depth::C256,
        "16" => Depth::C16,
        _ => Depth::True,
    };
    let nearest = args.iter().any(|a| a == "--no-dither");
    let dither = opt("--dither").unwrap_or_else(|| "none".into());
    let work = opt("--chafa-work").unwrap_or_else(|| "9".into());
    let runs: usize = opt("--runs").map(|r| r.parse()).transpose()?.unwrap_or(15);

    let (w, h, rgba) = read_png(path)?;
    let frame = Rgba {
        width: w as u32,
        height: h as u32,
        rgba: &rgba,
    };
    let (rw, rh) = (cols as usize * cw, rows as usize * ch);
    let reference_px = frame_at(&frame, rw, rh);
    let reference = luma_of(&reference_px);
    let lookup = glyph_lookup();
    println!(
        "{path}: {cols}×{rows} cells of {cw}×{ch} px, colours {colors}, ours {}, chafa --dither {dither}; SSIM against the frame",
        if nearest {
            "nearest colours"
        } else {
            "dithered"
        }
    );
    println!(
        "set        ours SSIM far   chafa SSIM far   ours bytes  chafa bytes  encode ms (median, min–max)  chafa symbols not drawn back"
    );
    for set in SymbolSet::ALL {
        let mut times = Vec::new();
        let mut ours = None;
        for _ in 0..runs {
            let t = Instant::now();
            let s = if nearest {
                Symbols::of(&frame, cols, rows, set)
            } else {
                Symbols::of_depth(&frame, cols, rows, set, depth)
            };
            let text = s.ansi(depth);
            times.push(t.elapsed().as_secs_f64() * 1e3);
            ours = Some(text);
        }
        times.sort_by(f64::total_cmp);
        let ours = ours.unwrap_or_default();
        let (ours_px, _) = draw_back(&ours, cols, rows, cw, ch, &lookup);
        let ours_ssim = ssim(&reference, &luma_of(&ours_px), rw, rh);
        let ours_far = far_error(&reference_px, &ours_px, rw, rh, ch);
        let chafa_set = match set {
            SymbolSet::Half => Some("vhalf"),
            SymbolSet::Quadrants => Some("quad"),
            SymbolSet::Sextants => Some("sextant"),
            SymbolSet::Braille => Some("braille"),
            // chafa 1.12 has no octants.
            SymbolSet::Octants => None,
        };
        let chafa = chafa_set.map(|c| chafa(path, cols, rows, c, &colors, &dither, &work));
        let (chafa_ssim, chafa_bytes, unknown) = match chafa {
            Some(Ok(text)) => {
                let (px, unknown) = draw_back(&text, cols, rows, cw, ch, &lookup);
                if std::env::var_os("CELLS").is_some() {
                    worst_cells(&reference, &reference_px, &ours_px, &px, rw, rh, cw, ch);
                }
                let mut u: Vec<String> = unknown.into_iter().map(|c| format!("{c}")).collect();
                u.sort();
                (
                    format!(
                        "{:.4} {:>5.2}",
                        ssim(&reference, &luma_of(&px), rw, rh),
                        far_error(&reference_px, &px, rw, rh, ch)
                    ),
                    text.len().to_string(),
                    u.join(""),
                )
            }
            Some(Err(e)) => (format!("error: {e}"), "-".into(), String::new()),
            None => ("-".into(), "-".into(), String::new()),
        };
        println!(
            "{:<10} {:.4} {:>5.2}  {:<15}  {:<10}  {:<11}  {:.2} ({:.2}–{:.2})  {}",
            set.name(),
            ours_ssim,
            ours_far,
            chafa_ssim,
            ours.len(),
            chafa_bytes,
            times[times.len() / 2],
            times[0],
            times[times.len() - 1],
            unknown
        );
    }
    Ok(())
}

fn chafa(
    path: &str,
    cols: u16,
    rows: u16,
    set: &str,
    colors: &str,
    dither: &str,
    work: &str,
) -> Result<String, String> {
    let out = Command::new("chafa")
        .args([
            "--format",
            "symbols",
            "--symbols",
            set,
            "--colors",
            colors,
            "--dither",
            dither,
            "--size",
            &format!("{cols}x{rows}"),
            "--stretch",
            "--work",
            work,
            "--animate",
            "off",
            path,
        ])
        .output()
        .map_err(|e| format!("chafa: {e}"))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

fn read_png(path: &str) -> Result<(usize, usize, Vec<u8>), Box<dyn std::error::Error>> {
    let mut dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path)?));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut r = dec.read_info()?;
    let mut buf = vec![0; r.output_buffer_size().ok_or("png too large")?];
    let info = r.next_frame(&mut buf)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let rgba = match info.color_type {
        png::ColorType::Rgba => buf[..w * h * 4].to_vec(),
        png::ColorType::Rgb => buf[..w * h * 3]
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        png::ColorType::Grayscale => buf[..w * h].iter().flat_map(|&g| [g, g, g, 255]).collect(),
        png::ColorType::GrayscaleAlpha => buf[..w * h * 2]
            .chunks_exact(2)
            .flat_map(|p| [p[0], p[0], p[0], 255])
            .collect(),
        other => return Err(format!("{path}: PNG colour type {other:?}").into()),
    };
    Ok((w, h, rgba))
}

/// The frame at `w` × `h` (nearest pixel: the frame is expected at that size).
fn frame_at(f: &Rgba<'_>, w: usize, h: usize) -> Vec<Colour> {
    let (fw, fh) = (f.width as usize, f.height as usize);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w * fw / w, i / w * fh / h);
            let p = &f.rgba[(y * fw + x) * 4..][..3];
            [p[0], p[1], p[2]]
        })
        .collect()
}

/// How a symbol covers its cell: a grid of `gw` × `gh` sub-cells, the lit
/// ones, and whether they are braille dots.
#[derive(Clone, Copy)]
struct Glyph {
    gw: usize,
    gh: usize,
    pattern: u32,
    dots: bool,
}

/// Every symbol of every set (the first set that has a symbol describes it).
fn glyph_lookup() -> HashMap<char, Glyph> {
    let mut m = HashMap::new();
    // A 1×1 cell: space is all background, `█` all foreground.
    m.insert(
        ' ',
        Glyph {
            gw: 1,
            gh: 1,
            pattern: 0,
            dots: false,
        },
    );
    m.insert(
        '█',
        Glyph {
            gw: 1,
            gh: 1,
            pattern: 1,
            dots: false,
        },
    );
    // The blank braille pattern, which chafa uses.
    m.insert(
        '\u{2800}',
        Glyph {
            gw: 1,
            gh: 1,
            pattern: 0,
            dots: false,
        },
    );
    for set in SymbolSet::ALL {
        let (gw, gh) = set.grid();
        for p in 0..(1u32 << (gw * gh)) {
            if let Some(c) = set.symbol(p as usize) {
                m.entry(c).or_insert(Glyph {
                    gw,
                    gh,
                    pattern: p,
                    dots: set == SymbolSet::Braille,
                });
            }
        }
    }
    // chafa's half blocks also use the left and right halves.
    m.entry('▌').or_insert(Glyph {
        gw: 2,
        gh: 1,
        pattern: 1,
        dots: false,
    });
    m.entry('▐').or_insert(Glyph {
        gw: 2,
        gh: 1,
        pattern: 2,
        dots: false,
    });
    m
}

/// An ANSI text frame drawn back to pixels: cells of `cw` × `ch`. Returns the
/// pixels and the symbols it could not draw (drawn as their background).
fn draw_back(
    text: &str,
    cols: u16,
    rows: u16,
    cw: usize,
    ch: usize,
    lookup: &HashMap<char, Glyph>,
) -> (Vec<Colour>, std::collections::BTreeSet<char>) {
    let (w, h) = (cols as usize * cw, rows as usize * ch);
    let mut px = vec![[0u8; 3]; w * h];
    let mut unknown = std::collections::BTreeSet::new();
    let (mut fg, mut bg): (Colour, Colour) = ([255; 3], [0; 3]);
    let mut inverse = false;
    let (mut col, mut row) = (0usize, 0usize);
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        if c == '\x1b' {
            if chars.peek() != Some(&'[') {
                continue;
            }
            chars.next();
            let mut seq = String::new();
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    seq.push(d);
                    break;
                }
                seq.push(d);
            }
            if let Some(params) = seq.strip_suffix('m') {
                let v: Vec<u32> = params.split(';').map(|p| p.parse().unwrap_or(0)).collect();
                let mut i = 0;
                while i < v.len() {
                    match v[i] {
                        0 => {
                            (fg, bg, inverse) = ([255; 3], [0; 3], false);
                        }
                        7 => inverse = true,
                        27 => inverse = false,
                        39 => fg = [255; 3],
                        49 => bg = [0; 3],
                        38 | 48 if v.get(i + 1) == Some(&2) && i + 4 < v.len() => {
                            let c = [v[i + 2] as u8, v[i + 3] as u8, v[i + 4] as u8];
                            if v[i] == 38 {
                                fg = c
                            } else {
                                bg = c
                            }
                            i += 4;
                        }
                        38 | 48 if v.get(i + 1) == Some(&5) && i + 2 < v.len() => {
                            let c = palette256_rgb(v[i + 2] as u8);
                            if v[i] == 38 {
                                fg = c
                            } else {
                                bg = c
                            }
                            i += 2;
                        }
                        n @ 30..=37 => fg = palette256_rgb((n - 30) as u8),
                        n @ 40..=47 => bg = palette256_rgb((n - 40) as u8),
                        n @ 90..=97 => fg = palette256_rgb((n - 82) as u8),
                        n @ 100..=107 => bg = palette256_rgb((n - 92) as u8),
                        _ => {}
                    }
                    i += 1;
                }
            }
            continue;
        }
        if c == '\n' {
            (col, row) = (0, row + 1);
            continue;
        }
        if c == '\r' {
            col = 0;
            continue;
        }
        if col >= cols as usize || row >= rows as usize {
            col += 1;
            continue;
        }
        let (f, b) = if inverse { (bg, fg) } else { (fg, bg) };
        let g = lookup.get(&c).copied().unwrap_or_else(|| {
            unknown.insert(c);
            Glyph {
                gw: 1,
                gh: 1,
                pattern: 0,
                dots: false,
            }
        });
        for y in 0..ch {
            for x in 0..cw {
                // Sub-cell j spans [⌊j·cw/gw⌋, ⌊(j+1)·cw/gw⌋), as foot and
                // kitty divide a cell (e.g. thirds of 16 rows: 5, 5, 6).
                let sub = |v: usize, size: usize, n: usize| {
                    (0..n).rev().find(|&j| j * size / n <= v).unwrap_or(0)
                };
                let (sx, sy) = (sub(x, cw, g.gw), sub(y, ch, g.gh));
                let mut on = g.pattern >> (sy * g.gw + sx) & 1 == 1;
                if on && g.dots {
                    // A dot: the middle half of its sub-cell each way.
                    let (sw, sh) = (cw as f32 / g.gw as f32, ch as f32 / g.gh as f32);
                    // (Braille grids are 2×4: 8×16 cells divide evenly.)
                    let (u, v) = (
                        (x as f32 + 0.5 - sx as f32 * sw) / sw,
                        (y as f32 + 0.5 - sy as f32 * sh) / sh,
                    );
                    on = (0.25..0.75).contains(&u) && (0.25..0.75).contains(&v);
                }
                px[(row * ch + y) * w + col * cw + x] = if on { f } else { b };
            }
        }
        col += 1;
    }
    (px, unknown)
}

/// The colour error seen from a little way off: both pictures averaged over
/// squares of `side` pixels (a cell's height: two cells of 8×16 side by side),
/// then the mean distance between the squares' RGB colours (0–441). Banding
/// and a palette's colour shifts show here; dither noise finer than a square
/// does not.
fn far_error(a: &[Colour], b: &[Colour], w: usize, h: usize, side: usize) -> f64 {
    let (mut total, mut n) = (0f64, 0usize);
    for y0 in (0..h - side + 1).step_by(side) {
        for x0 in (0..w - side + 1).step_by(side) {
            let mut d = [0f64; 3];
            for y in y0..y0 + side {
                for x in x0..x0 + side {
                    for (k, dk) in d.iter_mut().enumerate() {
                        *dk += a[y * w + x][k] as f64 - b[y * w + x][k] as f64;
                    }
                }
            }
            let m = (side * side) as f64;
            total += d.iter().map(|v| (v / m).powi(2)).sum::<f64>().sqrt();
            n += 1;
        }
    }
    total / n.max(1) as f64
}

fn luma_of(px: &[Colour]) -> Vec<f32> {
    px.iter()
        .map(|c| 0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32)
        .collect()
}

/// Mean SSIM of two luma pictures (Wang et al. 2004, Gaussian 11×11, σ 1.5).
fn ssim(a: &[f32], b: &[f32], w: usize, h: usize) -> f64 {
    let m = ssim_map(a, b, w, h);
    m.iter().map(|v| *v as f64).sum::<f64>() / (w * h) as f64
}

fn ssim_map(a: &[f32], b: &[f32], w: usize, h: usize) -> Vec<f32> {
    let k: Vec<f32> = {
        let v: Vec<f32> = (-5..=5)
            .map(|i: i32| (-(i * i) as f32 / (2.0 * 1.5 * 1.5)).exp())
            .collect();
        let s: f32 = v.iter().sum();
        v.into_iter().map(|x| x / s).collect()
    };
    let blur = |img: &[f32]| -> Vec<f32> {
        let mut t = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    let xx = (x as i32 + j as i32 - 5).clamp(0, w as i32 - 1) as usize;
                    s += kv * img[y * w + xx];
                }
                t[y * w + x] = s;
            }
        }
        let mut o = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    let yy = (y as i32 + j as i32 - 5).clamp(0, h as i32 - 1) as usize;
                    s += kv * t[yy * w + x];
                }
                o[y * w + x] = s;
            }
        }
        o
    };
    let prod = |p: &[f32], q: &[f32]| p.iter().zip(q).map(|(x, y)| x * y).collect::<Vec<f32>>();
    let (ma, mb) = (blur(a), blur(b));
    let (saa, sbb, sab) = (blur(&prod(a, a)), blur(&prod(b, b)), blur(&prod(a, b)));
    let (c1, c2) = ((0.01f32 * 255.0).powi(2), (0.03f32 * 255.0).powi(2));
    (0..w * h)
        .map(|i| {
            let (mx, my) = (ma[i], mb[i]);
            let (vx, vy, cxy) = (saa[i] - mx * mx, sbb[i] - my * my, sab[i] - mx * my);
            ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        })
        .collect()
}

/// Where chafa's text frame beats ours (`CELLS=1`): the SSIM map of each
/// summed cell by cell; the totals by what each draws there (black or not);
/// then the twelve cells where chafa gains most, each as the mean colours of
/// its 2 × 4 sub-cells in the frame, ours and chafa's.
#[allow(clippy::too_many_arguments)]
fn worst_cells(
    reference: &[f32],
    reference_px: &[Colour],
    ours: &[Colour],
    theirs: &[Colour],
    w: usize,
    h: usize,
    cw: usize,
    ch: usize,
) {
    let (ma, mb) = (
        ssim_map(reference, &luma_of(ours), w, h),
        ssim_map(reference, &luma_of(theirs), w, h),
    );
    let (cols, rows) = (w / cw, h / ch);
    let cell = |r: usize, c: usize| {
        (r * ch..(r + 1) * ch).flat_map(move |y| (c * cw..(c + 1) * cw).map(move |x| y * w + x))
    };
    let mut gains: Vec<(f32, usize, usize)> = Vec::new();
    let mut by_class = [[0f32; 2]; 4];
    for r in 0..rows {
        for c in 0..cols {
            let g: f32 = cell(r, c).map(|i| mb[i] - ma[i]).sum();
            let lit = |px: &[Colour]| cell(r, c).any(|i| px[i] != [0; 3]);
            let class = lit(ours) as usize + 2 * lit(theirs) as usize;
            by_class[class][(g < 0.0) as usize] += g;
            gains.push((g, r, c));
        }
    }
    gains.sort_by(|a, b| b.0.total_cmp(&a.0));
    println!(
        "  chafa − ours, SSIM summed over pixels: chafa ahead / ours ahead where both draw black {:.1} / {:.1}, only ours draws {:.1} / {:.1}, only chafa {:.1} / {:.1}, both {:.1} / {:.1}",
        by_class[0][0],
        by_class[0][1],
        by_class[1][0],
        by_class[1][1],
        by_class[2][0],
        by_class[2][1],
        by_class[3][0],
        by_class[3][1]
    );
    let mean = |px: &[Colour], x0: usize, y0: usize, x1: usize, y1: usize| {
        let mut t = [0u32; 3];
        for y in y0..y1 {
            for x in x0..x1 {
                for k in 0..3 {
                    t[k] += px[y * w + x][k] as u32;
                }
            }
        }
        t.map(|v| v / ((x1 - x0) * (y1 - y0)) as u32)
    };
    for &(g, r, c) in gains.iter().take(12) {
        let (x0, y0) = (c * cw, r * ch);
        let mut line = format!("  row {r} col {c} +{g:.1}:");
        for (name, px) in [("frame", reference_px), ("ours", ours), ("chafa", theirs)] {
            line += &format!(" {name}");
            for sy in 0..4 {
                for sx in 0..2 {
                    let m = mean(
                        px,
                        x0 + sx * cw / 2,
                        y0 + sy * ch / 4,
                        x0 + (sx + 1) * cw / 2,
                        y0 + (sy + 1) * ch / 4,
                    );
                    line += &format!(" {},{},{}", m[0], m[1], m[2]);
                }
            }
        }
        println!("{line}");
    }
}
