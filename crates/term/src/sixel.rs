//! A fast sixel encoder for rendered frames: the frame reduced to at most 256
//! colours ([`super::palette`]), then per 6-row band one pass that collects each
//! colour's column masks, and only the colours present, run-length encoded (`!n`).
//!
//! The frame's most common colour (the background) is painted first in every band
//! as one full-width run; the other colours overwrite it where they are, so empty
//! sky costs a few bytes per band. The image is declared with raster attributes
//! `"1;1;W;H` (square pixels, exact size); a last band shorter than six rows sets
//! only the bits of its rows.
//!
//! Why not icy_sixel (through ratatui-image or viuer): its quantizer and dithering
//! took ~97 ms for a 1200×800 frame on the project's 2-core machine, more than the
//! whole key-to-frame budget (`bench/RESULTS.md`).

use super::palette::{self, Indexed};

/// Colours per frame. Measured on 1200×800 frames (`benches/sixel_png.rs`): 32
/// adaptive colours cost fewer bytes than a fixed 6×6×6 cube with a grey ramp
/// (254 K against 274 K for a height-coloured synthetic scan, 113 K against 122 K
/// for Autzen in its own RGB) and keep muted colours that the cube turned grey;
/// 64 colours cost 28–32% more bytes, 256 more than twice as many.
pub const COLORS: usize = 32;

/// Why a frame could not be encoded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SixelError {
    #[error("an image of {width}×{height} pixels has nothing to draw")]
    Empty { width: u32, height: u32 },
    #[error("{len} bytes of RGBA do not make a {width}×{height} image")]
    WrongSize { len: usize, width: u32, height: u32 },
    #[error("an image {width} pixels wide is wider than sixel columns are counted here (65536)")]
    TooWide { width: usize },
    #[error("{len} palette indices into {colors} colours do not make a {width}×{height} image")]
    BadIndexed {
        len: usize,
        colors: usize,
        width: usize,
        height: usize,
    },
}

/// Appends the decimal digits of `n`.
fn push_number(out: &mut Vec<u8>, mut n: usize) {
    let mut digits = [0u8; 20];
    let mut i = digits.len();
    loop {
        i -= 1;
        digits[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    out.extend_from_slice(&digits[i..]);
}

/// Appends `n` copies of the sixel character `ch`, as `!n` + `ch` when shorter.
fn push_run(out: &mut Vec<u8>, ch: u8, n: usize) {
    if n <= 3 {
        for _ in 0..n {
            out.push(ch);
        }
    } else {
        out.push(b'!');
        push_number(out, n);
        out.push(ch);
    }
}

/// One colour's sixels in a band: `(column, mask)` in increasing column order.
#[derive(Default)]
struct Columns(Vec<(u16, u8)>);

/// Emits one colour's columns as runs, from column 0 (after `#c` or `$`).
fn push_columns(out: &mut Vec<u8>, cols: &[(u16, u8)]) {
    let mut cursor = 0usize;
    let mut run: (u8, usize) = (0, 0);
    for &(x, m) in cols {
        let x = x as usize;
        let ch = 63 + m;
        if x > cursor {
            // The gap: nothing of this colour in these columns.
            if run.0 == b'?' {
                run.1 += x - cursor;
            } else {
                push_run(out, run.0, run.1);
                run = (b'?', x - cursor);
            }
        }
        if run.0 == ch {
            run.1 += 1;
        } else {
            push_run(out, run.0, run.1);
            run = (ch, 1);
        }
        cursor = x + 1;
    }
    push_run(out, run.0, run.1);
}

/// Colours of a frame sent while the camera moves: with half-resolution frames
/// enlarged, 114 K against 165 K at 32 colours for a 1200×800 frame
/// (`benches/tui_latency.rs`, bench/RESULTS.md).
pub const MOVING_COLORS: usize = 16;

/// Encodes an RGBA image (alpha ignored) as one sixel image: `ESC P … ESC \`.
pub fn encode(rgba: &[u8], width: u32, height: u32) -> Result<String, SixelError> {
    encode_colors(rgba, width, height, COLORS)
}

/// [`encode`] with at most `colors` colours.
pub fn encode_colors(
    rgba: &[u8],
    width: u32,
    height: u32,
    colors: usize,
) -> Result<String, SixelError> {
    if width == 0 || height == 0 {
        return Err(SixelError::Empty { width, height });
    }
    let (w, h) = (width as usize, height as usize);
    if w.checked_mul(h).and_then(|n| n.checked_mul(4)) != Some(rgba.len()) {
        return Err(SixelError::WrongSize {
            len: rgba.len(),
            width,
            height,
        });
    }
    encode_indexed(&palette::reduce(rgba, colors), w, h)
}

/// Encodes an indexed image of `w × h` pixels: `indices.len() == w·h`, every index
/// within the palette.
pub fn encode_indexed(image: &Indexed, w: usize, h: usize) -> Result<String, SixelError> {
    let idx = &image.indices;
    let bad = || SixelError::BadIndexed {
        len: idx.len(),
        colors: image.palette.len(),
        width: w,
        height: h,
    };
    if w == 0 || h == 0 || w.checked_mul(h) != Some(idx.len()) {
        return Err(bad());
    }
    if w > u16::MAX as usize + 1 {
        return Err(SixelError::TooWide { width: w });
    }
    let mut used = [0u64; 256];
    for &c in idx.iter() {
        used[c as usize] += 1;
    }
    if used[image.palette.len().min(256)..].iter().any(|&n| n > 0) {
        return Err(bad());
    }
    let bg = (0..256)
        .max_by_key(|&c| (used[c], std::cmp::Reverse(c)))
        .unwrap_or(0);

    let mut out: Vec<u8> = Vec::with_capacity(64 * 1024);
    out.extend_from_slice(b"\x1bP0;1;0q\"1;1;");
    push_number(&mut out, w);
    out.push(b';');
    push_number(&mut out, h);
    for (c, &n) in used.iter().enumerate() {
        let Some(rgb) = image.palette.get(c).filter(|_| n > 0) else {
            continue;
        };
        out.push(b'#');
        push_number(&mut out, c);
        out.extend_from_slice(b";2");
        for &v in rgb {
            out.push(b';');
            push_number(&mut out, (v as usize * 100 + 127) / 255);
        }
    }

    let mut columns: Vec<Columns> = (0..256).map(|_| Columns::default()).collect();
    let mut present: Vec<u8> = Vec::with_capacity(256);
    let bands = h.div_ceil(6);
    for band in 0..bands {
        let y0 = band * 6;
        let rows = (h - y0).min(6);
        let rows_px: Vec<&[u8]> = (0..rows)
            .map(|r| &idx[(y0 + r) * w..(y0 + r + 1) * w])
            .collect();
        present.clear();
        for x in 0..w {
            for (r, row) in rows_px.iter().enumerate() {
                let c = row[x];
                if c as usize == bg {
                    continue;
                }
                let list = &mut columns[c as usize].0;
                match list.last_mut() {
                    Some(last) if last.0 as usize == x => last.1 |= 1 << r,
                    _ => {
                        if list.is_empty() {
                            present.push(c);
                        }
                        list.push((x as u16, 1 << r));
                    }
                }
            }
        }
        // The background first, whole band; then the rest over it.
        out.push(b'#');
        push_number(&mut out, bg);
        push_run(&mut out, 63 + ((1u8 << rows) - 1), w);
        present.sort_unstable();
        for &c in &present {
            out.push(b'$');
            out.push(b'#');
            push_number(&mut out, c as usize);
            let list = &mut columns[c as usize].0;
            push_columns(&mut out, list);
            list.clear();
        }
        if band + 1 < bands {
            out.push(b'-');
        }
    }
    out.extend_from_slice(b"\x1b\\");
    // Only ASCII was written.
    Ok(String::from_utf8(out).unwrap_or_default())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sixel image decoded: size, colour registers (percent RGB) and, per pixel,
    /// the register that painted it last (`None`: never painted).
    struct Decoded {
        width: usize,
        height: usize,
        registers: std::collections::HashMap<usize, [u32; 3]>,
        pixels: Vec<Option<usize>>,
    }

    fn number(s: &[u8], i: &mut usize) -> usize {
        let start = *i;
        while *i < s.len() && s[*i].is_ascii_digit() {
            *i += 1;
        }
        std::str::from_utf8(&s[start..*i]).unwrap().parse().unwrap()
    }

    /// A strict decoder for what [`encode`] writes; panics on anything else.
    fn decode(s: &str) -> Decoded {
        let s = s.as_bytes();
        assert!(s.starts_with(b"\x1bP0;1;0q"), "DCS header");
        assert!(s.ends_with(b"\x1b\\"), "string terminator");
        let body = &s[8..s.len() - 2];
        let mut i = 0;
        assert_eq!(body[i], b'"');
        i += 1;
        let pan = number(body, &mut i);
        i += 1;
        let pad = number(body, &mut i);
        assert_eq!((pan, pad), (1, 1), "square pixels");
        i += 1;
        let width = number(body, &mut i);
        assert_eq!(body[i], b';');
        i += 1;
        let height = number(body, &mut i);
        let mut d = Decoded {
            width,
            height,
            registers: Default::default(),
            pixels: vec![None; width * height],
        };
        let (mut x, mut band, mut colour) = (0usize, 0usize, None::<usize>);
        while i < body.len() {
            let b = body[i];
            match b {
                b'#' => {
                    i += 1;
                    let c = number(body, &mut i);
                    if body.get(i) == Some(&b';') {
                        i += 1;
                        assert_eq!(number(body, &mut i), 2, "RGB colour space");
                        let mut rgb = [0u32; 3];
                        for v in &mut rgb {
                            assert_eq!(body[i], b';');
                            i += 1;
                            *v = number(body, &mut i) as u32;
                            assert!(*v <= 100);
                        }
                        assert!(d.registers.insert(c, rgb).is_none(), "defined twice");
                    } else {
                        assert!(d.registers.contains_key(&c), "#{c} used before defined");
                        colour = Some(c);
                    }
                }
                b'$' => {
                    x = 0;
                    i += 1;
                }
                b'-' => {
                    x = 0;
                    band += 1;
                    i += 1;
                }
                b'!' | 63..=126 => {
                    let n = if b == b'!' {
                        i += 1;
                        let n = number(body, &mut i);
                        assert!(n > 3, "a repeat no shorter than the plain run");
                        n
                    } else {
                        1
                    };
                    let ch = body[i];
                    assert!((63..=126).contains(&ch), "sixel character");
                    i += 1;
                    let bits = ch - 63;
                    for _ in 0..n {
                        assert!(x < width, "sixel past the right edge");
                        for r in 0..6 {
                            if bits & (1 << r) != 0 {
                                let y = band * 6 + r;
                                assert!(y < height, "sixel below the last row");
                                d.pixels[y * width + x] = Some(colour.expect("a colour"));
                            }
                        }
                        x += 1;
                    }
                }
                o => panic!("unexpected byte {o} at {i}"),
            }
        }
        d
    }

    fn percent(v: u8) -> u32 {
        (v as u32 * 100 + 127) / 255
    }

    /// Encodes, decodes, and checks every pixel against the quantized input.
    fn round_trip(rgba: &[u8], w: u32, h: u32) -> String {
        let s = encode(rgba, w, h).unwrap();
        let d = decode(&s);
        assert_eq!((d.width, d.height), (w as usize, h as usize));
        let q = palette::reduce(rgba, COLORS);
        for (i, (&want, got)) in q.indices.iter().zip(&d.pixels).enumerate() {
            let got = got.unwrap_or_else(|| panic!("pixel {i} never painted"));
            assert_eq!(
                got,
                want as usize,
                "pixel ({}, {})",
                i % w as usize,
                i / w as usize
            );
            let p = q.palette[want as usize];
            assert_eq!(d.registers[&got], p.map(percent));
        }
        s
    }

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> Vec<u8> {
        let mut v = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let [r, g, b] = f(x, y);
                v.extend_from_slice(&[r, g, b, 255]);
            }
        }
        v
    }

    /// A small deterministic generator (no extra dependency).
    fn noise(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    #[test]
    fn a_noisy_image_decodes_back_pixel_for_pixel() {
        let mut rnd = noise(42);
        let (w, h) = (37, 23);
        let px: Vec<[u8; 3]> = (0..w * h)
            .map(|_| {
                let v = rnd();
                [v as u8, (v >> 8) as u8, (v >> 16) as u8]
            })
            .collect();
        let rgba = image(w, h, |x, y| px[(y * w + x) as usize]);
        round_trip(&rgba, w, h);
    }

    #[test]
    fn heights_that_are_not_multiples_of_six() {
        for h in 1..=13 {
            let rgba = image(9, h, |x, y| {
                if (x + y) % 3 == 0 {
                    [200, 30, 30]
                } else {
                    [0, 0, 0]
                }
            });
            let s = round_trip(&rgba, 9, h);
            // Bands: h/6 rounded up, separated by '-', none after the last.
            assert_eq!(
                s.matches('-').count(),
                (h as usize).div_ceil(6) - 1,
                "h = {h}"
            );
        }
    }

    #[test]
    fn a_sparse_cloud_on_black_is_small_and_exact() {
        // 1200×800 black with 3000 scattered points of a few colours.
        let (w, h) = (1200u32, 800u32);
        let mut rgba = image(w, h, |_, _| [0, 0, 0]);
        let mut rnd = noise(3);
        let colours = [[255, 200, 0], [40, 120, 255], [180, 180, 180]];
        for i in 0..3000 {
            let v = rnd();
            let (x, y) = ((v % w as u64) as usize, ((v >> 20) % h as u64) as usize);
            let c = colours[i % 3];
            rgba[(y * w as usize + x) * 4..][..3].copy_from_slice(&c);
        }
        let s = round_trip(&rgba, w, h);
        // The background is one run per band: no `?` runs spell out black.
        assert!(s.len() < 60_000, "{} bytes", s.len());
        assert!(s.contains("!1200~"));
    }

    #[test]
    fn runs_are_compressed() {
        let rgba = image(
            100,
            6,
            |x, _| if x < 50 { [255, 0, 0] } else { [0, 0, 255] },
        );
        let s = round_trip(&rgba, 100, 6);
        // A tie: the lower index (blue, 5) is the background, red goes over it.
        assert!(s.contains("!100~"), "{s}");
        assert!(s.contains("!50~"), "{s}");
        assert!(s.len() < 80, "{s}");
    }

    #[test]
    fn wrong_sizes_are_errors() {
        assert_eq!(
            encode(&[0; 12], 2, 2),
            Err(SixelError::WrongSize {
                len: 12,
                width: 2,
                height: 2
            })
        );
        assert!(matches!(encode(&[], 0, 5), Err(SixelError::Empty { .. })));
        let two = Indexed {
            palette: vec![[0, 0, 0], [9, 9, 9]],
            indices: vec![0, 1, 1, 0],
        };
        assert!(encode_indexed(&two, 2, 2).is_ok());
        assert!(matches!(
            encode_indexed(&two, 3, 2),
            Err(SixelError::BadIndexed { .. })
        ));
        let past = Indexed {
            indices: vec![0, 2, 1, 0],
            ..two
        };
        assert!(matches!(
            encode_indexed(&past, 2, 2),
            Err(SixelError::BadIndexed { .. })
        ));
    }
}
