//! Pictures as text: each terminal cell shows one symbol (a half block, a
//! quadrant, a sextant, an octant or a braille pattern) in a foreground and a
//! background colour, chosen to match the cell's pixels as closely as two
//! colours can, as chafa does.
//!
//! The frame is box-filtered to the symbol grid (2 pixels a cell for half
//! blocks, 2×2 for quadrants, 2×3 for sextants, 2×4 for octants and braille),
//! so a thin line or a single point in a larger frame survives as blended
//! colour. Means are truncated, as chafa's are: rounding to the nearest left
//! a faint haze (values of 1–2) over black backgrounds that SSIM counts
//! against the picture (on the bench frames truncation moved SSIM by
//! +0.0000–0.0007 and the colour error from afar from 0.03–0.09 to
//! 0.10–0.20, chafa's being 0.12–0.19). Where the cell does not divide
//! evenly (sextants of a 16-pixel cell are 5, 5 and 6 rows, as terminals
//! draw them) the fit weighs each sub-pixel by the frame pixels it covers.
//! Splits are ranked by luma-weighted error ([`WR`]); the two colours are
//! the groups' means. The box filter and, in 24-bit, the fit run a row at a
//! time in parallel. For each cell every symbol of the set is a split of its sub-pixels
//! into two groups; the best split is the one with the least squared error
//! when each group takes its mean colour. That error is the cell's total
//! variance less `|S₁|²/n₁ + |S₀|²/n₀` (the groups' sums and counts), so the
//! search needs only the sums of each pattern's pixels, which one pass over
//! the 2ⁿ patterns gives ([`Cell::fit`]): the exact best split, not an
//! approximation, at under a microsecond a cell.
//!
//! Our own rather than a crate's: no crate does this choice (chafa is C, and
//! its output is what [`bench/text.sh`] compares against).
//!
//! The escape string sets a colour only when it changes, in 24-bit, 256 or 16
//! colours ([`Depth`]); a cell whose split is no better than one colour is a
//! space on its background.
//!
//! In 256 and 16 colours ([`Symbols::of_depth`]) mapping the two colours to
//! the nearest palette entries bands a smooth gradient (a scan coloured by
//! height) into flat stripes. There the fit is done in the palette: for the
//! one colour and the [`REWEIGHED`] best splits, each group takes the palette
//! colour of least cost, and the least total wins, which often draws a cell
//! whose two means fall on one palette colour as a space. The cost is the
//! squared error plus [`SSIM_WEIGHT`] times SSIM's luminance loss, which
//! weighs an error by how dark the place is: grey 8 over black is as far
//! from the picture as white over grey. Each sub-pixel's loss counts the
//! black blocks of the frame under it apart from the rest ([`dark_share`]):
//! a speck on black is drawn black, not as a haze over its whole sub-pixel,
//! while an even dim area keeps a dim colour. A braille dot is a quarter of
//! its sub-pixel, so a lit group's cost is that of the dot's colour mixed
//! with the background's. And the error is diffused, Floyd–Steinberg between
//! cells (serpentine): a cell's pixels take on the error passed to it, and
//! half of the mean difference between them and the cell as drawn goes on to
//! the next cells. Passing each sub-pixel's own error on instead was slower
//! for a slightly lower SSIM; passing all of it on drew the bench frames
//! worse (see [`DIFFUSED`]). Against each 24-bit cell's colours mapped to the
//! nearest palette entries, on the airborne bench frames: seen from afar
//! (frame and text averaged over two cells) the colour error is 0–30 % lower
//! in 16 colours and −1 to 15 % in 256, with −23 to +13 % bytes in 16 colours
//! and 1–11 % fewer in 256, at an SSIM within 0.0012 but for braille (the
//! dots costed as they draw: 0.001–0.003 lower in 256 colours and
//! 0.005–0.008 in 16, with a third less colour error there; still above
//! chafa's). It is deterministic, and a palette
//! colour's flat area stays flat (no error to pass on). 24-bit output is not
//! touched.
//!
//! Braille in 16 colours is chosen another way, by how the cell would draw
//! (analysis by synthesis, [`by_synthesis`]): the costs above see each
//! sub-pixel's mean only, but a braille dot is a point of colour a quarter
//! of its sub-cell, and where the frame is an even texture of single points
//! (the building's dim brown walls: points of luma 178 among black, means of
//! luma 15–50), the per-group fit drew bright dots over black where the
//! means were highest. SSIM, whose windows are about a sub-cell wide, sees
//! that as contrast the frame does not have and black where its local mean
//! is lit: that one case stayed behind chafa (0.9710 against 0.9715) through
//! some fifteen variants of the fit (history 48). So each cell that is not
//! black takes the frame's luma statistics under each sub-cell ([`SubStat`]:
//! mean, variance, the mean of the middle half each way, where a dot shows,
//! and of the ring around it) and, for every pair of the
//! [`SYNTH_COLOURS`] palette colours of least cost as a flat colour (and
//! black) as background and dots, dots each sub-cell or not as costs less:
//! squared RGB error of the mean shown plus [`SSIM_WEIGHT`] times 1 − SSIM
//! of the sub-cell's pixels as drawn (one window a sub-cell), from those
//! statistics (a dot's luma variance, its covariance with the frame's
//! middle). The least total wins, a flat colour included. The error
//! diffused is then that of the cell as it shows, a dot a quarter of its
//! sub-pixel (with the per-group fit that was worse, history 48; here it
//! raised SSIM by up to 0.0012 and cut the colour error from afar by
//! 12–30 %). On the bench
//! frames (`text_quality`, against chafa 1.12 `--dither none`): building
//! 0.9710 → 0.9735 (chafa 0.9715), lamppost 0.9865 → 0.9873, airborne
//! 0.8889 → 0.9006 from above and 0.9121 → 0.9199 at 35°; the colour error
//! from afar 0.68 → 0.58, 0.35 → 0.29, 3.69 → 3.05 and 3.10 → 2.41. Faster
//! than the fit it replaces there (it needs no pattern sums). Tried (with
//! the error diffused as drawn whole): keeping the fit's own choice and
//! colours as candidates as well, lower on the airborne frames (0.8994,
//! 0.9189) and a third slower; adding the colour a dot needs to show the
//! brightest sub-cell over black, 0.001–0.003 lower there; all 16 colours
//! paired (with the fit's), 0.002 lower from above at four times the time;
//! the SSIM weight 5,000 (SSIM 0.001–0.006 lower) and 60,000 (up to 0.003
//! higher, the colour error from afar 4–10 % larger); with the error as
//! shown, 10,000 and 40,000 moved SSIM by −0.003 to +0.0012 and the colour
//! error by −14 to +15 %. In 256 colours braille was already above chafa
//! and keeps the fit.

use crate::Rgba;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write;
use std::sync::OnceLock;

/// An RGB colour.
pub type Colour = [u8; 3];

/// The frame pixels (along one axis of `f`) that pixel `i` of `n` covers:
/// `[a, b)`, at least one.
fn span(i: usize, n: usize, f: usize) -> (usize, usize) {
    let a = i * f / n;
    (a, ((i + 1) * f / n).max(a + 1))
}

/// `frame` at half its size each way (2 × 2 means; a last odd row or column
/// alone).
fn halve(frame: &Rgba<'_>) -> Vec<u8> {
    let (fw, fh) = (frame.width as usize, frame.height as usize);
    let (w, h) = (fw.div_ceil(2), fh.div_ceil(2));
    let mut out = vec![0u8; w * h * 4];
    for y in 0..h {
        for x in 0..w {
            let mut sum = [0u32; 4];
            let mut n = 0;
            for yy in 2 * y..(2 * y + 2).min(fh) {
                for xx in 2 * x..(2 * x + 2).min(fw) {
                    let p = &frame.rgba[(yy * fw + xx) * 4..][..4];
                    for k in 0..4 {
                        sum[k] += p[k] as u32;
                    }
                    n += 1;
                }
            }
            for k in 0..4 {
                out[(y * w + x) * 4 + k] = (sum[k] / n) as u8;
            }
        }
    }
    out
}

/// `frame` as `w` × `h` pixels, row by row, each the mean of the frame pixels
/// it covers (rounded to the nearest); a frame smaller than that is enlarged
/// by repeating pixels, and an empty frame is black.
fn box_filter(frame: &Rgba<'_>, w: usize, h: usize) -> Vec<Colour> {
    let (fw, fh) = (frame.width as usize, frame.height as usize);
    let mut out = vec![[0u8; 3]; w * h];
    if w == 0 || h == 0 || fw == 0 || fh == 0 || frame.rgba.len() < fw * fh * 4 {
        return out;
    }
    if fw.div_ceil(w) * fh.div_ceil(h) > 1 << 24 {
        // More than 2^24 frame pixels an output pixel: shrink by half first.
        let half = halve(frame);
        let f = Rgba {
            width: frame.width.div_ceil(2),
            height: frame.height.div_ceil(2),
            rgba: &half,
        };
        return box_filter(&f, w, h);
    }
    let xs: Vec<(usize, usize)> = (0..w).map(|x| span(x, w, fw)).collect();
    // Output rows in parallel, each summing its frame rows a line at a time
    // (the frame is read in order, once).
    out.par_chunks_mut(w).enumerate().for_each(|(y, line_out)| {
        let (y0, y1) = span(y, h, fh);
        // Four lanes a pixel (alpha summed and ignored) so the adds are one
        // vector add; u32 holds 2^24 pixels of 255.
        let mut acc = vec![[0u32; 4]; w];
        for row in y0..y1 {
            let line = &frame.rgba[row * fw * 4..(row + 1) * fw * 4];
            for (a, &(x0, x1)) in acc.iter_mut().zip(&xs) {
                for px in line[x0 * 4..x1 * 4].chunks_exact(4) {
                    for k in 0..4 {
                        a[k] += px[k] as u32;
                    }
                }
            }
        }
        for ((o, a), &(x0, x1)) in line_out.iter_mut().zip(&acc).zip(&xs) {
            let n = ((x1 - x0) * (y1 - y0)) as u32;
            // Truncated, as chafa's means are: SSIM weighs the faint haze that
            // rounding up leaves on a black background (see `bench/text.sh`).
            *o = [a[0] / n, a[1] / n, a[2] / n].map(|s| s as u8);
        }
    });
    out
}

/// The luma statistics ([`SubStat`]) of the frame pixels `[x0, x1)` ×
/// `[y0, y1)`; the middle is the middle half of them each way, where a
/// braille dot shows.
fn sub_stat(frame: &Rgba<'_>, (x0, x1): (usize, usize), (y0, y1): (usize, usize)) -> SubStat {
    let fw = frame.width as usize;
    let middle = |a: usize, b: usize| {
        let q = (b - a) / 4;
        (a + q, b - q)
    };
    let ((i0, i1), (m0, m1)) = (middle(x0, x1), middle(y0, y1));
    // Luma ×16 (Rec. 601 in integers): sums, squares, the middle's sum.
    let (mut s, mut q, mut m) = (0u64, 0u64, 0u64);
    for row in y0..y1 {
        let line = &frame.rgba[(row * fw + x0) * 4..(row * fw + x1) * 4];
        let (mut rs, mut rq, mut rm) = (0u32, 0u64, 0u32);
        let mid = (m0..m1).contains(&row);
        for (x, px) in line.chunks_exact(4).enumerate() {
            let l = (77 * px[0] as u32 + 150 * px[1] as u32 + 29 * px[2] as u32) >> 4;
            rs += l;
            rq += (l * l) as u64;
            if mid && (i0..i1).contains(&(x0 + x)) {
                rm += l;
            }
        }
        s += rs as u64;
        q += rq;
        m += rm as u64;
    }
    let n = ((x1 - x0) * (y1 - y0)) as f32;
    let n_in = ((i1 - i0) * (m1 - m0)) as f32;
    let mu = s as f32 / 16.0 / n;
    let m_in = m as f32 / 16.0 / n_in;
    SubStat {
        mu,
        var: (q as f32 / 256.0 / n - mu * mu).max(0.0),
        m_in,
        m_out: if n > n_in {
            (s - m) as f32 / 16.0 / (n - n_in)
        } else {
            m_in
        },
    }
}

/// For each of `w` × `h` output pixels (as [`box_filter`]), the share of the
/// frame pixels it covers that lie in black blocks: blocks of
/// [`DARK_BLOCK`]² frame pixels (from the output pixel's corner; smaller at
/// its far edges) whose channels average at most [`DARK`]. A frame no
/// larger than the output has blocks of one pixel.
fn dark_share(frame: &Rgba<'_>, w: usize, h: usize) -> Vec<f32> {
    let (fw, fh) = (frame.width as usize, frame.height as usize);
    let mut out = vec![0f32; w * h];
    if w == 0 || h == 0 || fw == 0 || fh == 0 || frame.rgba.len() < fw * fh * 4 {
        return out;
    }
    let xs: Vec<(usize, usize)> = (0..w).map(|x| span(x, w, fw)).collect();
    out.par_chunks_mut(w).enumerate().for_each(|(y, line_out)| {
        let (y0, y1) = span(y, h, fh);
        // Each frame column's sum of its brightest channel over a band of
        // block rows, then the black pixels each output pixel has.
        let mut column = vec![0u32; fw];
        let mut dark = vec![0u32; w];
        let mut band = y0;
        while band < y1 {
            let end = (band + DARK_BLOCK).min(y1);
            column.fill(0);
            for row in band..end {
                let line = &frame.rgba[row * fw * 4..(row + 1) * fw * 4];
                for (s, px) in column.iter_mut().zip(line.chunks_exact(4)) {
                    *s += px[0].max(px[1]).max(px[2]) as u32;
                }
            }
            let rows = (end - band) as u32;
            for (d, &(x0, x1)) in dark.iter_mut().zip(&xs) {
                let mut x = x0;
                while x < x1 {
                    let e = (x + DARK_BLOCK).min(x1);
                    let n = (e - x) as u32 * rows;
                    if column[x..e].iter().sum::<u32>() <= DARK as u32 * n {
                        *d += n;
                    }
                    x = e;
                }
            }
            band = end;
        }
        for ((o, d), &(x0, x1)) in line_out.iter_mut().zip(&dark).zip(&xs) {
            *o = *d as f32 / ((x1 - x0) * (y1 - y0)) as f32;
        }
    });
    out
}

/// Which symbols cells are drawn with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SymbolSet {
    /// `▀` over its background: 1×2 pixels, every terminal and font.
    Half,
    /// The 16 quadrant block elements (`▘▝▀▖▌▞▛▗▚▐▜▄▙▟█`): 2×2, in every
    /// monospace font since Unicode 1.
    Quadrants,
    /// Sextants (Unicode 13, U+1FB00…): 2×3.
    Sextants,
    /// Octants (Unicode 16, U+1CD00…, with the quadrants and the quarter
    /// blocks `▂▆🮂🮅`): 2×4; 250 of the 256 patterns (the four single corners
    /// and the middle quarters, whose code points lie in a block of Unicode 16
    /// we have not checked, are left out: the fit draws them with a near one).
    Octants,
    /// Braille patterns (U+2800…): 2×4 dots, in most fonts.
    Braille,
}

impl SymbolSet {
    /// Every set, in the order `--symbols` lists them.
    pub const ALL: [SymbolSet; 5] = [
        SymbolSet::Half,
        SymbolSet::Quadrants,
        SymbolSet::Sextants,
        SymbolSet::Octants,
        SymbolSet::Braille,
    ];

    /// Sub-pixels a cell: columns, rows.
    pub fn grid(self) -> (usize, usize) {
        match self {
            SymbolSet::Half => (1, 2),
            SymbolSet::Quadrants => (2, 2),
            SymbolSet::Sextants => (2, 3),
            SymbolSet::Octants | SymbolSet::Braille => (2, 4),
        }
    }

    /// The name `--symbols` takes and messages use.
    pub fn name(self) -> &'static str {
        match self {
            SymbolSet::Half => "half",
            SymbolSet::Quadrants => "quadrants",
            SymbolSet::Sextants => "sextants",
            SymbolSet::Octants => "octants",
            SymbolSet::Braille => "braille",
        }
    }

    /// The set a name (or its first letters: `quad`, `sext`, `oct`) names.
    pub fn parse(s: &str) -> Option<SymbolSet> {
        let s = s.trim().to_ascii_lowercase();
        if s.len() < 3 {
            return None;
        }
        SymbolSet::ALL
            .into_iter()
            .find(|set| set.name().starts_with(&s))
    }

    /// The symbol this set draws `pattern` with (bit `r·w + c` the sub-pixel
    /// at column `c`, row `r`), if it has one.
    pub fn symbol(self, pattern: usize) -> Option<char> {
        self.glyphs().get(pattern).copied().flatten()
    }

    /// The symbol of each pattern this set draws: bit `r·w + c` is the
    /// sub-pixel at column `c`, row `r` (`w` the grid's width). Patterns the
    /// set cannot draw are `None`; pattern 0 is a space.
    fn glyphs(self) -> &'static [Option<char>] {
        &self.table().glyphs
    }

    /// The table for `frame` over `cols` × `rows` cells where its sub-pixels
    /// cover unequal numbers of frame pixels (the first cell's, as the box
    /// filter divides it: sextants of a 16-pixel cell are 5, 5 and 6 rows), so
    /// the fit weighs each as the terminal draws it; `None` where they are
    /// equal (the shared [`SymbolSet::table`]).
    fn weighed(self, frame: &Rgba<'_>, cols: u16, rows: u16) -> Option<Table> {
        let (gw, gh) = self.grid();
        let cell = |g: usize, cells: u16, f: u32| -> Vec<f32> {
            let n = g * cells as usize;
            (0..g)
                .map(|j| {
                    let (a, b) = span(j, n, f as usize);
                    (b - a) as f32
                })
                .collect()
        };
        let (wx, wy) = (cell(gw, cols, frame.width), cell(gh, rows, frame.height));
        if wx.iter().all(|&v| v == wx[0]) && wy.iter().all(|&v| v == wy[0]) {
            return None;
        }
        let mut weight = [1f32; 8];
        for y in 0..gh {
            for x in 0..gw {
                weight[y * gw + x] = wx[x] * wy[y];
            }
        }
        Some(Table::weighed(self, weight))
    }

    fn table(self) -> &'static Table {
        static TABLES: [OnceLock<Table>; 5] = [const { OnceLock::new() }; 5];
        let i = SymbolSet::ALL.iter().position(|&s| s == self).unwrap_or(0);
        TABLES[i].get_or_init(|| Table::new(self))
    }
}

impl std::str::FromStr for SymbolSet {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        SymbolSet::parse(s).ok_or_else(|| {
            format!("unknown symbols '{s}' (half, quadrants, sextants, octants, braille)")
        })
    }
}

impl std::fmt::Display for SymbolSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The quadrant symbol of each 2×2 pattern (bits: upper left, upper right,
/// lower left, lower right).
const QUADRANTS: [char; 16] = [
    ' ', '▘', '▝', '▀', '▖', '▌', '▞', '▛', '▗', '▚', '▐', '▜', '▄', '▙', '▟', '█',
];

/// Octant patterns (bits row by row, two a row) whose symbols are not in the
/// U+1CD00 block: the quadrants, the empty and full cell, the single corners,
/// and the quarter blocks (upper, lower, middle left and right, three
/// quarters). The block holds every other pattern in increasing order.
const OCTANTS_ELSEWHERE: [u8; 26] = [
    0, 1, 2, 3, 5, 10, 15, 20, 40, 63, 64, 80, 85, 90, 95, 128, 160, 165, 170, 175, 192, 240, 245,
    250, 252, 255,
];

fn glyph_table(set: SymbolSet) -> Vec<Option<char>> {
    let (w, h) = set.grid();
    let n = 1usize << (w * h);
    let mut t = vec![None; n];
    match set {
        SymbolSet::Half => {
            t[0] = Some(' ');
            t[1] = Some('▀');
            t[2] = Some('▄');
            t[3] = Some('█');
        }
        SymbolSet::Quadrants => {
            for (p, &c) in QUADRANTS.iter().enumerate() {
                t[p] = Some(c);
            }
        }
        SymbolSet::Sextants => {
            // U+1FB00 + p − 1, skipping the patterns that are the left and
            // right halves (21 and 42: `▌` `▐`); 0 and 63 are space and `█`.
            for p in 1..63usize {
                t[p] = match p {
                    21 => Some('▌'),
                    42 => Some('▐'),
                    _ => {
                        let skip = (p > 21) as u32 + (p > 42) as u32;
                        char::from_u32(0x1FB00 + p as u32 - 1 - skip)
                    }
                };
            }
            t[0] = Some(' ');
            t[63] = Some('█');
        }
        SymbolSet::Octants => {
            let mut next = 0x1CD00u32;
            for p in 0..256usize {
                if OCTANTS_ELSEWHERE.contains(&(p as u8)) {
                    // Rows of two bits: the quadrant whose both rows agree.
                    let rows = [p & 3, (p >> 2) & 3, (p >> 4) & 3, (p >> 6) & 3];
                    t[p] = if rows[0] == rows[1] && rows[2] == rows[3] {
                        Some(QUADRANTS[rows[0] | rows[2] << 2])
                    } else if p == 3 {
                        Some('\u{1FB82}') // upper one quarter
                    } else if p == 63 {
                        Some('\u{1FB85}') // upper three quarters
                    } else if p == 192 {
                        Some('▂')
                    } else if p == 252 {
                        Some('▆')
                    } else {
                        None
                    };
                } else {
                    t[p] = char::from_u32(next);
                    next += 1;
                }
            }
        }
        SymbolSet::Braille => {
            // Braille numbers its dots down the left column (1 2 3, then 7),
            // then the right (4 5 6, then 8).
            const DOT: [u32; 8] = [0x01, 0x08, 0x02, 0x10, 0x04, 0x20, 0x40, 0x80];
            for (p, slot) in t.iter_mut().enumerate() {
                let mut bits = 0;
                for (i, d) in DOT.iter().enumerate() {
                    if p >> i & 1 == 1 {
                        bits |= d;
                    }
                }
                *slot = char::from_u32(0x2800 + bits);
            }
            t[0] = Some(' ');
        }
    }
    t
}

/// One cell: its symbol and its two colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cell {
    pub symbol: char,
    pub fg: Colour,
    pub bg: Colour,
}

impl Cell {
    /// The best cell for these sub-pixels (`px.len()` = the set's grid) with
    /// the symbols of `table`.
    fn fit(px: &[Colour], table: &Table) -> Cell {
        let n = px.len();
        let full = (1usize << n) - 1;
        if px.iter().all(|c| *c == px[0]) {
            return Cell {
                symbol: ' ',
                fg: px[0],
                bg: px[0],
            };
        }
        let Sums { r, g, b, score } = Sums::of(px, table);
        let (tr, tg, tb) = (r[full], g[full], b[full]);
        // One colour, then the patterns in order of fewer lit sub-pixels: a
        // pattern and its complement score the same, and the one with fewer
        // wins (a braille dot is smaller than its sub-cell, so the foreground
        // should be the fewer dots).
        let mut best = (
            (WR * tr * tr + WG * tg * tg + WB * tb * tb) / table.whole,
            0usize,
        );
        for &p in &table.order {
            let p = p as usize;
            if score[p] > best.0 {
                best = (score[p], p);
            }
        }
        let p = best.1;
        let mean = |s: [f32; 3], k: f32| s.map(|v| (v / k) as u8);
        if p == 0 {
            let c = mean([tr, tg, tb], table.whole);
            return Cell {
                symbol: ' ',
                fg: c,
                bg: c,
            };
        }
        let k = table.lit[p];
        let fg = mean([r[p], g[p], b[p]], k);
        let bg = mean([tr - r[p], tg - g[p], tb - b[p]], table.whole - k);
        if fg == bg {
            return Cell {
                symbol: ' ',
                fg: bg,
                bg,
            };
        }
        Cell {
            symbol: table.glyphs[p].unwrap_or(' '),
            fg,
            bg,
        }
    }
}

/// How much each channel's error counts when splits are ranked: the luma
/// weights (Rec. 601, times 3 so grey weighs as before), as the eye and SSIM
/// see a cell. The colours are still each group's mean, whatever the weights.
const WR: f32 = 0.299 * 3.0;
const WG: f32 = 0.587 * 3.0;
const WB: f32 = 0.114 * 3.0;

/// How many of the best splits (by the exact fit) [`fit_quantized`] weighs
/// again with palette colours.
const REWEIGHED: usize = 2;

/// What a palette colour costs a group of sub-pixels beside its squared RGB
/// error: this many times its SSIM luminance loss. SSIM (the bench's measure,
/// and close to what the eye sees) compares local means *relatively*, `1 −
/// (a − b)² / (a² + b² + C₁)`: on a black background the darkest grey over
/// black costs as much as white over grey, where squared error calls it
/// nothing. Without this term, in 256 and 16 colours the diffused error
/// built up into a haze of the darkest grey over sparse points and dim
/// texture turned black, and chafa scored 0.0001–0.0008 higher on the thin
/// and dim frames. 20,000 was the best of 3,000–200,000 on the bench frames
/// (`bash bench/text.sh`; history 48).
const SSIM_WEIGHT: f32 = 20_000.0;

/// SSIM's C₁ for 8-bit values: (0.01 · 255)².
const C1: f32 = 6.5025;

/// A channel value at most this is black, for [`dark_share`].
const DARK: u8 = 2;

/// The side of the blocks [`dark_share`] looks at, in frame pixels: about
/// the span of SSIM's 11 × 11 Gaussian window (σ 1.5). Single black pixels
/// between lit ones are not a black area to the eye or to SSIM; 3 and 5 did
/// as well or worse on the bench frames, 8 worse.
const DARK_BLOCK: usize = 4;

/// The Rec. 601 luma of a colour, 0–255.
fn luma(c: Colour) -> f32 {
    luma_of(c.map(|v| v as f32))
}

/// [`luma`] of a colour in `f32` (a mix of palette colours).
fn luma_of(c: [f32; 3]) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// What [`fit_quantized`] knows of a cell's sub-pixels beyond their colours:
/// how much of each lies in black areas of the frame ([`dark_share`]) and
/// the luma of the rest.
#[derive(Clone, Copy, Default)]
struct Shade {
    /// The share of the sub-pixel in black blocks, 0–1.
    dark: [f32; 8],
    /// The mean luma of the rest of it.
    lit: [f32; 8],
}

impl Shade {
    /// For sub-pixels `px` (each with the error passed to it) of which
    /// `dark` lies in black blocks.
    fn of(px: &[Colour], dark: &[f32; 8]) -> Shade {
        let mut s = Shade {
            dark: *dark,
            lit: [0.0; 8],
        };
        for (j, c) in px.iter().enumerate() {
            if dark[j] < 1.0 {
                s.lit[j] = luma(*c) / (1.0 - dark[j]);
            }
        }
        s
    }
}

/// The best cell for these sub-pixels with colours of `depth`'s palette: the
/// one colour and the [`REWEIGHED`] best splits of the exact fit, each group
/// taking the palette colour of least cost ([`pick`]: squared error and the
/// SSIM luminance loss); the least total wins. Braille's foreground is drawn
/// as dots a quarter of their sub-pixel, so its cost is that of the dot's
/// colour mixed with the background's. Returns the pattern (0: one colour)
/// and the colours.
fn fit_quantized(
    px: &[Colour],
    dark: &[f32; 8],
    table: &Table,
    depth: Depth,
) -> (usize, Colour, Colour) {
    let n = px.len();
    let full = (1usize << n) - 1;
    let shade = Shade::of(px, dark);
    let (c, q) = pick(px, &shade, table, full, depth, None);
    if px.iter().all(|c| *c == px[0]) {
        return (0, q, q);
    }
    let Sums { score, .. } = Sums::of(px, table);
    // The best splits, best first (ties: fewer lit sub-pixels, as in the fit).
    let mut top = [(f32::NEG_INFINITY, 0usize); REWEIGHED];
    for &p in &table.order {
        let p = p as usize;
        if score[p] > top[REWEIGHED - 1].0 {
            let mut i = REWEIGHED - 1;
            while i > 0 && score[p] > top[i - 1].0 {
                top[i] = top[i - 1];
                i -= 1;
            }
            top[i] = (score[p], p);
        }
    }
    let mut best = (c, 0usize, q, q);
    for &(sc, p) in &top {
        if sc == f32::NEG_INFINITY {
            break;
        }
        let (c0, q0) = pick(px, &shade, table, full & !p, depth, None);
        if c0 >= best.0 {
            continue;
        }
        let on = table.dots.then_some(q0);
        let (c1, q1) = pick(px, &shade, table, p, depth, on);
        if q1 != q0 && c1 + c0 < best.0 {
            best = (c1 + c0, p, q1, q0);
        }
    }
    (best.1, best.2, best.3)
}

/// The palette colour of least cost for the sub-pixels of `mask`, and that
/// cost: the squared RGB error (weighed as the sub-pixels are) plus
/// [`SSIM_WEIGHT`] times the SSIM luminance loss. `on`: the group is
/// braille dots over this background, each showing a quarter dot's colour
/// and three quarters background. The squared error alone is a lower bound
/// of the cost, so a candidate whose error is no better than the best cost
/// so far is not weighed further.
fn pick(
    px: &[Colour],
    shade: &Shade,
    table: &Table,
    mask: usize,
    depth: Depth,
    on: Option<Colour>,
) -> (f32, Colour) {
    // The group's weight k, sums S and Σ w·|p|², for the squared error
    // k·|q|² − 2·S·q + Σ w·|p|².
    let (mut k, mut sum, mut sq) = (0f32, [0f32; 3], 0f32);
    for (j, c) in px.iter().enumerate() {
        if mask >> j & 1 == 1 {
            let w = table.weight[j];
            let c = c.map(|v| v as f32);
            for i in 0..3 {
                sum[i] += c[i] * w;
            }
            sq += w * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
            k += w;
        }
    }
    let mean = sum.map(|v| (v / k) as u8);
    // The loss's terms: the black shares' weight in one, and each lit
    // share's weight and luma.
    let (mut dark, mut lit, mut n_lit) = (0f32, [(0f32, 0f32); 8], 0);
    for j in 0..px.len() {
        if mask >> j & 1 == 1 {
            let w = table.weight[j] * SSIM_WEIGHT;
            dark += w * shade.dark[j];
            if shade.dark[j] < 1.0 {
                lit[n_lit] = (w * (1.0 - shade.dark[j]), shade.lit[j]);
                n_lit += 1;
            }
        }
    }
    let mut best = (f32::INFINITY, [0u8; 3]);
    let mut weigh = |q: Colour| {
        let shown = match on {
            Some(b) => [0, 1, 2].map(|i| (q[i] as f32 + 3.0 * b[i] as f32) * 0.25),
            None => q.map(|v| v as f32),
        };
        let mut cost = k * (shown[0] * shown[0] + shown[1] * shown[1] + shown[2] * shown[2])
            - 2.0 * (sum[0] * shown[0] + sum[1] * shown[1] + sum[2] * shown[2])
            + sq;
        if cost >= best.0 {
            return;
        }
        let y = luma_of(shown);
        let y2 = y * y;
        cost += dark * y2 / (y2 + C1);
        for &(w, yl) in &lit[..n_lit] {
            let d = yl - y;
            cost += w * d * d / (yl * yl + y2 + C1);
        }
        if cost < best.0 {
            best = (cost, q);
        }
    };
    // The nearest colour first: its cost bounds the others'.
    weigh(quantize(mean, depth));
    match depth {
        Depth::True => {}
        Depth::C16 => ANSI16.into_iter().for_each(&mut weigh),
        Depth::C256 => {
            // The cube colours around the mean (each channel's level below
            // and above it) and the greys either side of it.
            let around = |v: u8| {
                let i = CUBE.iter().rposition(|&l| l <= v).unwrap_or(0);
                [CUBE[i], CUBE[(i + 1).min(5)]]
            };
            let (r, g, b) = (around(mean[0]), around(mean[1]), around(mean[2]));
            for r in r {
                for g in g {
                    for b in b {
                        weigh([r, g, b]);
                    }
                }
            }
            let m = (mean[0] as i32 + mean[1] as i32 + mean[2] as i32) / 3;
            let i = ((m - 8).max(0) / 10).min(23);
            for i in [i, (i + 1).min(23)] {
                weigh([(8 + 10 * i) as u8; 3]);
            }
        }
    }
    best
}

/// The colour the terminal shows for `c` at `depth`: `c` itself in 24-bit, else
/// the palette colour [`colour_code`] picks.
fn quantize(c: Colour, depth: Depth) -> Colour {
    match depth {
        Depth::True => c,
        Depth::C256 => palette256_rgb(palette256(c)),
        Depth::C16 => ANSI16[ansi16(c) as usize],
    }
}

/// The share of a cell's error passed on to the cells after it. All of it
/// (Floyd and Steinberg's) drew the airborne bench frames worse than half,
/// from afar as well as by SSIM, and from above in 16 colours worse than none
/// (the errors a 16-colour palette leaves are large: passed on whole, they
/// overshoot, we suppose). Of 0.35, 0.5, 0.65 and 1, half balances the colour
/// error from afar and SSIM best (bench/RESULTS.md, "Text mode").
const DIFFUSED: f32 = 0.5;

/// The cells of `px` (`cols` × `rows` cells of `set`'s grid, row by row) in
/// `depth`'s palette, with the error diffused: the cells are fitted row by row,
/// every other row right to left; each cell's sub-pixels first take on the
/// error passed to the cell (clamped to 0–255), and the mean difference
/// between them and the cell as drawn, times [`DIFFUSED`], goes to the next
/// cell in the row (7/16) and to the three cells below (3/16, 5/16, 1/16:
/// Floyd and Steinberg's weights, a cell for a pixel). A cell's mean, not
/// each sub-pixel's own error: that kept the symbols' edges sharper (SSIM) at
/// the same colour error from afar, and cost less.
#[allow(clippy::too_many_arguments)]
fn dithered(
    px: &[Colour],
    darks: &[f32],
    frame: Option<&Rgba<'_>>,
    cols: usize,
    rows: usize,
    set: SymbolSet,
    table: &Table,
    depth: Depth,
) -> Vec<Cell> {
    let blank = Cell {
        symbol: ' ',
        fg: [0; 3],
        bg: [0; 3],
    };
    let mut cells = vec![blank; cols * rows];
    if cols == 0 {
        return cells;
    }
    cells
        .par_chunks_mut(cols * BAND)
        .enumerate()
        .for_each(|(b, band)| {
            dither_band(px, darks, frame, cols, b * BAND, band, set, table, depth)
        });
    cells
}

/// Rows of cells [`dithered`] diffuses its error within, each band on its
/// own (so the bands are fitted in parallel): a seam every 20 rows, which on
/// the bench frames moved SSIM by −0.0006 to +0.0001 and halved the time to
/// encode 40 rows on two cores.
const BAND: usize = 20;

/// [`dithered`]'s rows from `r0`, into `cells` (whole rows).
#[allow(clippy::too_many_arguments)]
fn dither_band(
    px: &[Colour],
    darks: &[f32],
    frame: Option<&Rgba<'_>>,
    cols: usize,
    r0: usize,
    cells: &mut [Cell],
    set: SymbolSet,
    table: &Table,
    depth: Depth,
) {
    let (gw, gh) = set.grid();
    let n = gw * gh;
    let w = cols * gw;
    // The error passed to each cell of this row and of the next, a cell of
    // margin either side.
    let mut here = vec![[0f32; 3]; cols + 2];
    let mut below = here.clone();
    let mut sub = [[0u8; 3]; 8];
    let mut dark = [0f32; 8];
    for r in r0..r0 + cells.len() / cols {
        let forward = r % 2 == 0;
        for i in 0..cols {
            let c = if forward { i } else { cols - 1 - i };
            let e = here[c + 1];
            // The sum of the cell's pixels as fitted (with the error).
            let mut total = [0f32; 3];
            for y in 0..gh {
                for x in 0..gw {
                    let p = px[(r * gh + y) * w + c * gw + x];
                    let j = y * gw + x;
                    dark[j] = darks[(r * gh + y) * w + c * gw + x];
                    for k in 0..3 {
                        // (+0.5 and a cast round a non-negative value without
                        // a libm call.)
                        let v = ((p[k] as f32 + e[k]).clamp(0.0, 255.0) + 0.5) as u8;
                        total[k] += v as f32 * table.weight[j];
                        sub[j][k] = v;
                    }
                }
            }
            // Braille in 16 colours: a cell with anything lit is chosen by
            // its pixels ([`by_synthesis`]); a black one as in the others.
            let lit = frame.filter(|_| {
                (0..gh).any(|y| (0..gw).any(|x| px[(r * gh + y) * w + c * gw + x] != [0; 3]))
            });
            let (pattern, fg, bg) = match lit {
                Some(frame) if n == 8 => {
                    let (h, fw, fh) = (px.len() / w, frame.width as usize, frame.height as usize);
                    let mut st = [SubStat::default(); 8];
                    for y in 0..gh {
                        for x in 0..gw {
                            let (xs, ys) = (span(c * gw + x, w, fw), span(r * gh + y, h, fh));
                            st[y * gw + x] = sub_stat(frame, xs, ys);
                        }
                    }
                    by_synthesis(&sub, &st, luma_of(e))
                }
                _ => fit_quantized(&sub[..n], &dark, table, depth),
            };
            cells[(r - r0) * cols + c] = Cell {
                symbol: table.glyphs[pattern].unwrap_or(' '),
                fg,
                bg,
            };
            // The mean error: the pixels' sum less the drawn colours' sum.
            let (mut k1, whole) = (table.lit[pattern], table.whole);
            if frame.is_some() {
                // Braille chosen by its pixels: the dots as they show, a
                // quarter of their sub-pixels (see the module's doc).
                k1 *= 0.25;
            }
            let d = [0, 1, 2].map(|k| {
                let drawn = fg[k] as f32 * k1 + bg[k] as f32 * (whole - k1);
                (total[k] - drawn) / whole * DIFFUSED
            });
            if d == [0.0; 3] {
                continue;
            }
            let (next, back) = if forward { (c + 2, c) } else { (c, c + 2) };
            for k in 0..3 {
                here[next][k] += d[k] * (7.0 / 16.0);
                below[back][k] += d[k] * (3.0 / 16.0);
                below[c + 1][k] += d[k] * (5.0 / 16.0);
                below[next][k] += d[k] * (1.0 / 16.0);
            }
        }
        std::mem::swap(&mut here, &mut below);
        below.fill([0.0; 3]);
    }
}

/// What [`by_synthesis`] knows of a braille sub-cell's frame pixels: the
/// mean and variance of their luma, and the mean luma of the middle half
/// each way (where a dot shows) and of the ring around it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct SubStat {
    mu: f32,
    var: f32,
    m_in: f32,
    m_out: f32,
}

/// SSIM's C₂ for 8-bit values: (0.03 · 255)².
const C2: f32 = 58.5225;

/// How many palette colours, those of least cost as a flat colour over the
/// cell (and black besides), [`by_synthesis`] pairs as background and dots.
/// 3, 5 and 6 scored within 0.0006 of 4 on the bench frames; all 16 took
/// four times the time for less.
const SYNTH_COLOURS: usize = 4;

/// A braille cell's [`SubStat`]s and colours, a lane a sub-cell, so each
/// candidate's eight costs are one vectorised loop.
struct Lanes {
    /// The sub-cells' colours (with the error passed to the cell), by
    /// channel.
    m: [[f32; 8]; 3],
    mu: [f32; 8],
    /// `mu` with the luma of the error passed to the cell (0–255).
    mx: [f32; 8],
    var: [f32; 8],
    m_in: [f32; 8],
    m_out: [f32; 8],
}

impl Lanes {
    /// Each sub-cell's cost shown as background `b` alone, or as dots `d`
    /// over it: the squared RGB error of the mean shown (a dot a quarter of
    /// the sub-cell) plus [`SSIM_WEIGHT`] times 1 − SSIM of its pixels'
    /// luma, the dot drawn where it lies.
    #[inline(always)]
    fn costs(&self, b: &([f32; 3], f32), d: Option<&([f32; 3], f32)>) -> [f32; 8] {
        // What the sub-cell shows: its mean colour and luma, the luma's
        // variance, and the weights of the ring's and the middle's mean
        // luma in the covariance.
        let (shown, my, vy, (kb, kd)) = match d {
            None => (b.0, b.1, 0.0, (0.0, 0.0)),
            Some(d) => {
                let dl = d.1 - b.1;
                (
                    [0, 1, 2].map(|i| 0.75 * b.0[i] + 0.25 * d.0[i]),
                    0.75 * b.1 + 0.25 * d.1,
                    0.1875 * dl * dl,
                    (0.75 * b.1, 0.25 * d.1),
                )
            }
        };
        let mut out = [0f32; 8];
        for j in 0..8 {
            let (dr, dg, db) = (
                self.m[0][j] - shown[0],
                self.m[1][j] - shown[1],
                self.m[2][j] - shown[2],
            );
            // Cov(x, y): y is b on the ring and d in the middle. Alone (no
            // dot) it is 0, as kb·m_out = my·mu there.
            let cov = kb * self.m_out[j] + kd * self.m_in[j] - self.mu[j] * my;
            let cov = if d.is_some() { cov } else { 0.0 };
            let mx = self.mx[j];
            let ssim = ((2.0 * mx * my + C1) * (2.0 * cov + C2))
                / ((mx * mx + my * my + C1) * (self.var[j] + vy + C2));
            out[j] = dr * dr + dg * dg + db * db + SSIM_WEIGHT * (1.0 - ssim);
        }
        out
    }
}

/// A braille cell in 16 colours, chosen by how its pixels would draw
/// (analysis by synthesis): for the [`SYNTH_COLOURS`] palette colours of
/// least cost as a flat colour, and black, each as background with each
/// other as dots, every sub-cell takes a dot or not as costs less
/// ([`Lanes::costs`]: squared error of the mean shown plus the SSIM loss of
/// its pixels, the dot a quarter of the sub-cell in its middle); the least
/// total wins, a flat colour included. `px`: the sub-cells' colours (with
/// the error passed on), `st` their frame pixels, `el` the luma of the
/// error passed on. Returns the pattern (0: one colour) and the colours.
fn by_synthesis(px: &[Colour; 8], st: &[SubStat; 8], el: f32) -> (usize, Colour, Colour) {
    static PAL: OnceLock<[([f32; 3], f32); 16]> = OnceLock::new();
    let pal = PAL.get_or_init(|| ANSI16.map(|c| (c.map(|v| v as f32), luma(c))));
    let mut s = Lanes {
        m: [[0f32; 8]; 3],
        mu: st.map(|t| t.mu),
        mx: st.map(|t| (t.mu + el).clamp(0.0, 255.0)),
        var: st.map(|t| t.var),
        m_in: st.map(|t| t.m_in),
        m_out: st.map(|t| t.m_out),
    };
    for (j, c) in px.iter().enumerate() {
        for i in 0..3 {
            s.m[i][j] = c[i] as f32;
        }
    }
    let mut alone = [[0f32; 8]; 16];
    let mut sums = [0f32; 16];
    for (i, p) in pal.iter().enumerate() {
        alone[i] = s.costs(p, None);
        sums[i] = alone[i].iter().sum();
    }
    // The colours of least cost alone, least first, then black.
    let mut cand = [0usize; SYNTH_COLOURS + 1];
    let mut nc = 0;
    for i in 0..16 {
        if nc == SYNTH_COLOURS && sums[i] >= sums[cand[nc - 1]] {
            continue;
        }
        let mut at = nc.min(SYNTH_COLOURS - 1);
        nc = (nc + 1).min(SYNTH_COLOURS);
        while at > 0 && sums[i] < sums[cand[at - 1]] {
            cand[at] = cand[at - 1];
            at -= 1;
        }
        cand[at] = i;
    }
    if !cand[..nc].contains(&0) {
        cand[nc] = 0;
        nc += 1;
    }
    let b0 = cand[0];
    let (mut best_cost, mut best) = (sums[b0], (0, ANSI16[b0], ANSI16[b0]));
    for &bi in &cand[..nc] {
        for &di in &cand[..nc] {
            if di == bi {
                continue;
            }
            let on = s.costs(&pal[bi], Some(&pal[di]));
            let (mut cost, mut p) = (0f32, 0usize);
            for j in 0..8 {
                if on[j] < alone[bi][j] {
                    cost += on[j];
                    p |= 1 << j;
                } else {
                    cost += alone[bi][j];
                }
            }
            if p != 0 && cost < best_cost {
                best_cost = cost;
                best = (p, ANSI16[di], ANSI16[bi]);
            }
        }
    }
    best
}

/// The sum of the pixels of each pattern, channel by channel, and each
/// pattern's score `|S₁|²/n₁ + |S₀|²/n₀` (0 for the patterns the set cannot
/// draw): the fit's least squared error is the cell's variance less it.
struct Sums {
    r: [f32; 256],
    g: [f32; 256],
    b: [f32; 256],
    score: [f32; 256],
}

impl Sums {
    fn of(px: &[Colour], table: &Table) -> Sums {
        let full = (1usize << px.len()) - 1;
        // Each pattern from the one without its lowest bit.
        let (mut r, mut g, mut b) = ([0f32; 256], [0f32; 256], [0f32; 256]);
        for p in 1..=full {
            let (low, prev) = (p.trailing_zeros() as usize, p & (p - 1));
            let (c, w) = (px[low], table.weight[low]);
            r[p] = r[prev] + c[0] as f32 * w;
            g[p] = g[prev] + c[1] as f32 * w;
            b[p] = b[prev] + c[2] as f32 * w;
        }
        let (tr, tg, tb) = (r[full], g[full], b[full]);
        // Every pattern at once (a loop the compiler vectorises; patterns the
        // set cannot draw weigh 0).
        let mut score = [0f32; 256];
        for p in 0..=full {
            let (r1, g1, b1) = (r[p], g[p], b[p]);
            let (r0, g0, b0) = (tr - r1, tg - g1, tb - b1);
            score[p] = (WR * r1 * r1 + WG * g1 * g1 + WB * b1 * b1) * table.w1[p]
                + (WR * r0 * r0 + WG * g0 * g0 + WB * b0 * b0) * table.w0[p];
        }
        Sums { r, g, b, score }
    }
}

/// A set's symbols and what the fit needs of them.
struct Table {
    /// The symbol of each pattern, if the set draws it.
    glyphs: Vec<Option<char>>,
    /// How much of the cell each sub-pixel covers, in frame pixels (1 each
    /// where the cell divides evenly): sextants in a 16-pixel cell are 5, 5
    /// and 6 rows high, as terminals draw them, so the fit weighs them so.
    weight: [f32; 8],
    /// n₁, the weight of each pattern's lit sub-pixels, and n, the cell's.
    lit: [f32; 256],
    whole: f32,
    /// 1/n₁ and 1/n₀ (lit and unlit weight) of each pattern the set draws;
    /// 0 for the others.
    w1: [f32; 256],
    w0: [f32; 256],
    /// The patterns the set draws, neither empty nor full, fewest lit first.
    order: Vec<u16>,
    /// Braille: a lit sub-pixel shows its colour on a dot a quarter of it.
    dots: bool,
}

impl Table {
    fn new(set: SymbolSet) -> Table {
        Table::weighed(set, [1.0; 8])
    }

    /// The table for sub-pixels of these weights.
    fn weighed(set: SymbolSet, weight: [f32; 8]) -> Table {
        let glyphs = glyph_table(set);
        let n = set.grid().0 * set.grid().1;
        let full = (1usize << n) - 1;
        let mut lit = [0f32; 256];
        for p in 1..=full {
            lit[p] = lit[p & (p - 1)] + weight[p.trailing_zeros() as usize];
        }
        let whole = lit[full];
        let (mut w1, mut w0) = ([0f32; 256], [0f32; 256]);
        let mut order: Vec<u16> = (1..full)
            .filter(|&p| glyphs[p].is_some())
            .map(|p| p as u16)
            .collect();
        order.sort_by_key(|p| p.count_ones());
        for &p in &order {
            let k = lit[p as usize];
            w1[p as usize] = 1.0 / k;
            w0[p as usize] = 1.0 / (whole - k);
        }
        Table {
            glyphs,
            weight,
            lit,
            whole,
            w1,
            w0,
            order,
            dots: set == SymbolSet::Braille,
        }
    }
}

/// How many colours the terminal shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Depth {
    /// 24-bit (`COLORTERM=truecolor`, tmux's `RGB`/`Tc`).
    True,
    /// The xterm 256-colour palette.
    C256,
    /// The 16 ANSI colours.
    C16,
}

impl Depth {
    /// In a few words, for `doctor` and the status line.
    pub fn name(self) -> &'static str {
        match self {
            Depth::True => "24-bit colour",
            Depth::C256 => "256 colours",
            Depth::C16 => "16 colours",
        }
    }
}

/// How frames are drawn as text: the symbols and the colours.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TextStyle {
    pub set: SymbolSet,
    pub depth: Depth,
    /// Why this depth and set, in a few words.
    pub reason: String,
}

impl Default for TextStyle {
    fn default() -> TextStyle {
        TextStyle {
            set: SymbolSet::Quadrants,
            depth: Depth::True,
            reason: String::new(),
        }
    }
}

/// Terminals that draw sextants themselves (not from a font), by name (TERM,
/// TERM_PROGRAM, XTVERSION or tmux's account of the outer terminal).
fn draws_sextants(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    ["kitty", "wezterm", "foot", "ghostty", "contour"]
        .iter()
        .any(|t| n.contains(t))
}

/// Terminals whose name says they take 24-bit colour.
fn names_truecolor(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    n.ends_with("-direct")
        || [
            "kitty",
            "wezterm",
            "iterm",
            "ghostty",
            "foot",
            "alacritty",
            "contour",
            "rio",
        ]
        .iter()
        .any(|t| n.contains(t))
}

/// The text style for a terminal: 24-bit colour where `COLORTERM` says
/// `truecolor`/`24bit` (outside tmux), where tmux's features for the client
/// list `RGB` (tmux passes 24-bit colour on only then), or where the terminal
/// is known by name; else 256 colours where `TERM` says `256color`; else 16.
/// Quadrants everywhere (every monospace font has them), sextants where the
/// terminal draws them itself. `names`: the terminal's names, most precise
/// first; inside tmux, the outer terminal's.
pub fn choose_text(
    names: &[&str],
    term: Option<&str>,
    colorterm: Option<&str>,
    tmux_features: Option<&str>,
    in_tmux: bool,
) -> TextStyle {
    let colorterm = colorterm.unwrap_or("").to_ascii_lowercase();
    let term = term.unwrap_or("").to_ascii_lowercase();
    let (depth, why) = if in_tmux {
        match tmux_features {
            Some(f) if f.split(',').any(|x| matches!(x.trim(), "RGB" | "Tc")) => {
                (Depth::True, "tmux lists RGB".to_string())
            }
            Some(_) if term.contains("256color") => {
                (Depth::C256, format!("tmux without RGB, TERM={term}"))
            }
            Some(_) => (Depth::C16, format!("tmux without RGB, TERM={term}")),
            None if term.contains("256color") => {
                (Depth::C256, format!("tmux could not be asked, TERM={term}"))
            }
            None => (Depth::C16, format!("tmux could not be asked, TERM={term}")),
        }
    } else if colorterm == "truecolor" || colorterm == "24bit" {
        (Depth::True, format!("COLORTERM={colorterm}"))
    } else if let Some(n) = names.iter().find(|n| names_truecolor(n)) {
        (Depth::True, format!("{n} takes 24-bit colour"))
    } else if term.contains("256color") {
        (Depth::C256, format!("TERM={term}"))
    } else {
        (Depth::C16, format!("TERM={term}, no COLORTERM"))
    };
    let (set, set_why) = match names.iter().find(|n| draws_sextants(n)) {
        Some(n) => (SymbolSet::Sextants, format!("{n} draws sextants")),
        None => (SymbolSet::Quadrants, "quadrants, in every font".to_string()),
    };
    TextStyle {
        set,
        depth,
        reason: format!("{} ({why}), {set_why}", depth.name()),
    }
}

/// A picture as `cols` × `rows` cells of one symbol set, row by row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Symbols {
    pub cols: u16,
    pub rows: u16,
    pub set: SymbolSet,
    pub cells: Vec<Cell>,
}

impl Symbols {
    /// `frame` over `cols` × `rows` cells of `set`.
    pub fn of(frame: &Rgba<'_>, cols: u16, rows: u16, set: SymbolSet) -> Symbols {
        let (gw, gh) = set.grid();
        let (w, h) = (cols as usize * gw, rows as usize * gh);
        let px = box_filter(frame, w, h);
        let weighed = set.weighed(frame, cols, rows);
        let table = weighed.as_ref().unwrap_or(set.table());
        let blank = Cell {
            symbol: ' ',
            fg: [0; 3],
            bg: [0; 3],
        };
        let mut cells = vec![blank; cols as usize * rows as usize];
        // Rows of cells in parallel: each cell's fit is its own.
        cells
            .par_chunks_mut(cols.max(1) as usize)
            .enumerate()
            .for_each(|(r, line)| {
                let mut sub = [[0u8; 3]; 8];
                for (c, cell) in line.iter_mut().enumerate() {
                    for y in 0..gh {
                        for x in 0..gw {
                            sub[y * gw + x] = px[(r * gh + y) * w + c * gw + x];
                        }
                    }
                    *cell = Cell::fit(&sub[..gw * gh], table);
                }
            });
        Symbols {
            cols,
            rows,
            set,
            cells,
        }
    }

    /// `frame` over `cols` × `rows` cells of `set`, in the colours `depth`
    /// shows: in 24-bit the same cells as [`Symbols::of`]; in 256 or 16
    /// colours each cell fitted with palette colours and the error diffused
    /// ([`dithered`]), so a gradient that falls between palette colours is drawn
    /// as a mix of them rather than in bands. Its [`Symbols::ansi`] at `depth`
    /// writes the colours as they are.
    pub fn of_depth(
        frame: &Rgba<'_>,
        cols: u16,
        rows: u16,
        set: SymbolSet,
        depth: Depth,
    ) -> Symbols {
        if depth == Depth::True {
            return Symbols::of(frame, cols, rows, set);
        }
        let (gw, gh) = set.grid();
        let (c, r) = (cols as usize, rows as usize);
        let px = box_filter(frame, c * gw, r * gh);
        let darks = dark_share(frame, c * gw, r * gh);
        let weighed = set.weighed(frame, cols, rows);
        let table = weighed.as_ref().unwrap_or(set.table());
        // Braille in 16 colours is chosen by the frame's own pixels.
        let (fw, fh) = (frame.width as usize, frame.height as usize);
        let synth = set == SymbolSet::Braille
            && depth == Depth::C16
            && fw > 0
            && fh > 0
            && frame.rgba.len() >= fw * fh * 4;
        Symbols {
            cols,
            rows,
            set,
            cells: dithered(&px, &darks, synth.then_some(frame), c, r, set, table, depth),
        }
    }

    /// The cells of row `r`.
    pub fn row(&self, r: u16) -> &[Cell] {
        let w = self.cols as usize;
        &self.cells[r as usize * w..(r as usize + 1) * w]
    }

    /// The picture as text with colour escapes of `depth`, a line a row, the
    /// colours reset before each line break (so a scroll does not paint the
    /// new line); the cursor ends below the last row.
    pub fn ansi(&self, depth: Depth) -> String {
        let mut s = String::with_capacity(self.cells.len() * 8);
        for r in 0..self.rows {
            let (mut fg, mut bg): (Option<u32>, Option<u32>) = (None, None);
            for cell in self.row(r) {
                let b = colour_code(cell.bg, depth);
                if bg != Some(b) {
                    sgr(&mut s, b, depth, false);
                    bg = Some(b);
                }
                if cell.symbol != ' ' {
                    let f = colour_code(cell.fg, depth);
                    if fg != Some(f) {
                        sgr(&mut s, f, depth, true);
                        fg = Some(f);
                    }
                }
                s.push(cell.symbol);
            }
            s.push_str("\x1b[0m\n");
        }
        s
    }
}

/// The xterm palette's cube levels.
const CUBE: [u8; 6] = [0, 95, 135, 175, 215, 255];

/// The standard 16 colours as xterm draws them.
const ANSI16: [Colour; 16] = [
    [0, 0, 0],
    [205, 0, 0],
    [0, 205, 0],
    [205, 205, 0],
    [0, 0, 238],
    [205, 0, 205],
    [0, 205, 205],
    [229, 229, 229],
    [127, 127, 127],
    [255, 0, 0],
    [0, 255, 0],
    [255, 255, 0],
    [92, 92, 255],
    [255, 0, 255],
    [0, 255, 255],
    [255, 255, 255],
];

fn dist(a: Colour, b: Colour) -> i32 {
    let d = |i: usize| a[i] as i32 - b[i] as i32;
    d(0) * d(0) + d(1) * d(1) + d(2) * d(2)
}

/// The colour as the terminal is told it: 24-bit RGB packed, or a palette index.
fn colour_code(c: Colour, depth: Depth) -> u32 {
    match depth {
        Depth::True => (c[0] as u32) << 16 | (c[1] as u32) << 8 | c[2] as u32,
        Depth::C256 => palette256(c) as u32,
        Depth::C16 => ansi16(c) as u32,
    }
}

/// The nearest of the 16 ANSI colours (as xterm draws them; the first of
/// equals).
pub fn ansi16(c: Colour) -> u8 {
    let mut best = (i32::MAX, 0);
    for (i, &p) in ANSI16.iter().enumerate() {
        let d = dist(c, p);
        if d < best.0 {
            best = (d, i);
        }
    }
    best.1 as u8
}

/// The nearest cube level of each channel value (the lower of two equally
/// near), as a table: the dithered fit asks for palette colours a few times a
/// cell.
const CUBE_LEVEL: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut v = 0;
    while v < 256 {
        let mut best = 0;
        let mut i = 1;
        while i < 6 {
            if (CUBE[i] as i32 - v as i32).abs() < (CUBE[best] as i32 - v as i32).abs() {
                best = i;
            }
            i += 1;
        }
        t[v] = best as u8;
        v += 1;
    }
    t
};

/// The nearest colour of the xterm 256 palette's cube and grey ramp.
pub fn palette256(c: Colour) -> u8 {
    let level = |v: u8| CUBE_LEVEL[v as usize] as usize;
    let (r, g, b) = (level(c[0]), level(c[1]), level(c[2]));
    let cube = [CUBE[r], CUBE[g], CUBE[b]];
    let grey_i = ((c[0] as i32 + c[1] as i32 + c[2] as i32) / 3 - 3).clamp(0, 239) / 10;
    let grey_v = (8 + 10 * grey_i) as u8;
    if dist(c, [grey_v; 3]) < dist(c, cube) {
        232 + grey_i as u8
    } else {
        16 + (36 * r + 6 * g + b) as u8
    }
}

/// The 24-bit colour of a 256-palette index (16–255; 0–15 as xterm's).
pub fn palette256_rgb(i: u8) -> Colour {
    match i {
        0..=15 => ANSI16[i as usize],
        16..=231 => {
            let j = (i - 16) as usize;
            [CUBE[j / 36], CUBE[j / 6 % 6], CUBE[j % 6]]
        }
        _ => [8 + 10 * (i - 232); 3],
    }
}

fn sgr(s: &mut String, code: u32, depth: Depth, fg: bool) {
    let _ = match depth {
        Depth::True => {
            let (r, g, b) = (code >> 16, code >> 8 & 255, code & 255);
            write!(s, "\x1b[{};2;{r};{g};{b}m", if fg { 38 } else { 48 })
        }
        Depth::C256 => write!(s, "\x1b[{};5;{code}m", if fg { 38 } else { 48 }),
        Depth::C16 => {
            let base = match (fg, code < 8) {
                (true, true) => 30,
                (true, false) => 90 - 8,
                (false, true) => 40,
                (false, false) => 100 - 8,
            };
            write!(s, "\x1b[{}m", base + code)
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cell's sub-pixels from a pattern: `on` where the bit is set.
    fn cell_of(set: SymbolSet, p: usize, on: Colour, off: Colour) -> Vec<Colour> {
        let (w, h) = set.grid();
        (0..w * h)
            .map(|i| if p >> i & 1 == 1 { on } else { off })
            .collect()
    }

    #[test]
    fn every_pattern_a_set_draws_is_chosen_for_itself() {
        // Two colours laid out as a pattern come back as that pattern's
        // symbol (or its complement's, colours swapped), exactly.
        let (on, off) = ([250, 200, 10], [5, 6, 7]);
        for set in SymbolSet::ALL {
            let glyphs = set.glyphs();
            let full = glyphs.len() - 1;
            for p in 1..full {
                let Some(g) = glyphs[p] else { continue };
                let px = cell_of(set, p, on, off);
                let c = Cell::fit(&px, set.table());
                if c.symbol == g {
                    assert_eq!((c.fg, c.bg), (on, off), "{set} pattern {p}");
                } else {
                    assert_eq!(Some(c.symbol), glyphs[full ^ p], "{set} pattern {p}");
                    assert_eq!((c.fg, c.bg), (off, on), "{set} pattern {p}");
                }
            }
        }
    }

    #[test]
    fn an_edge_at_every_sub_cell_position() {
        // A vertical edge between the columns of a 2-wide cell is the left
        // half (`▌`) in every set that has it; a horizontal edge after row k
        // is the upper k rows.
        let (on, off) = ([255; 3], [0; 3]);
        for set in [
            SymbolSet::Quadrants,
            SymbolSet::Sextants,
            SymbolSet::Octants,
        ] {
            let (w, h) = set.grid();
            let left: usize = (0..h).map(|r| 1 << (r * w)).sum();
            let c = Cell::fit(&cell_of(set, left, on, off), set.table());
            assert_eq!((c.symbol, c.fg, c.bg), ('▌', on, off), "{set}");
            let g = set.glyphs();
            let full = g.len() - 1;
            for k in 1..h {
                let upper = (1 << (k * w)) - 1;
                let c = Cell::fit(&cell_of(set, upper, on, off), set.table());
                // The pattern, or its complement with the colours swapped.
                let ok = (Some(c.symbol) == g[upper] && (c.fg, c.bg) == (on, off))
                    || (Some(c.symbol) == g[full ^ upper] && (c.fg, c.bg) == (off, on));
                assert!(ok, "{set} edge after row {k}: {c:?}");
            }
        }
        assert_eq!(SymbolSet::Quadrants.glyphs()[3], Some('▀'));
        assert_eq!(SymbolSet::Sextants.glyphs()[3], Some('\u{1FB02}'));
        assert_eq!(SymbolSet::Octants.glyphs()[0b1111_1100], Some('▆'));
    }

    #[test]
    fn a_single_lit_sub_pixel_is_its_own_dot() {
        let (on, off) = ([255, 255, 0], [0; 3]);
        // Braille: each sub-pixel is its dot (1, 4, 2, 5, 3, 6, 7, 8).
        let dots = ['⠁', '⠈', '⠂', '⠐', '⠄', '⠠', '⡀', '⢀'];
        for (i, &d) in dots.iter().enumerate() {
            let c = Cell::fit(
                &cell_of(SymbolSet::Braille, 1 << i, on, off),
                SymbolSet::Braille.table(),
            );
            assert_eq!((c.symbol, c.fg, c.bg), (d, on, off));
        }
        // Sextant 1 is U+1FB00, the lower right U+1FB0B… by the formula.
        let c = Cell::fit(
            &cell_of(SymbolSet::Sextants, 1, on, off),
            SymbolSet::Sextants.table(),
        );
        assert_eq!(c.symbol, '\u{1FB00}');
        let c = Cell::fit(
            &cell_of(SymbolSet::Sextants, 32, on, off),
            SymbolSet::Sextants.table(),
        );
        assert_eq!(c.symbol, '\u{1FB1E}');
        // The octant set has no single corner: a lone lit corner is drawn
        // as the nearest split it has, and no colour is lost entirely.
        let c = Cell::fit(
            &cell_of(SymbolSet::Octants, 1, on, off),
            SymbolSet::Octants.table(),
        );
        assert_ne!(c.symbol, ' ');
        // In a uniform cell, nothing beats a space.
        let c = Cell::fit(&[[9, 9, 9]; 8], SymbolSet::Octants.table());
        assert_eq!((c.symbol, c.bg), (' ', [9, 9, 9]));
    }

    #[test]
    fn three_colours_split_where_the_error_is_least() {
        // Quadrants: red, red, dark blue, black: the blue and black go
        // together (their difference is the smallest), red on top.
        let px = [[200, 0, 0], [200, 0, 0], [0, 0, 40], [0, 0, 0]];
        let c = Cell::fit(&px, SymbolSet::Quadrants.table());
        assert_eq!((c.symbol, c.fg, c.bg), ('▀', [200, 0, 0], [0, 0, 20]));
    }

    #[test]
    fn the_tables_are_complete_and_distinct() {
        for set in SymbolSet::ALL {
            let g = set.glyphs();
            let drawn: Vec<char> = g.iter().flatten().copied().collect();
            let mut uniq = drawn.clone();
            uniq.sort_unstable();
            uniq.dedup();
            assert_eq!(uniq.len(), drawn.len(), "{set}: a symbol twice");
        }
        let oct = SymbolSet::Octants.glyphs();
        assert_eq!(oct.iter().flatten().count(), 250);
        assert_eq!(oct[0b1111_1110], Some('\u{1CDE5}'));
        assert_eq!(oct[4], Some('\u{1CD00}'));
        assert_eq!(SymbolSet::Sextants.glyphs().iter().flatten().count(), 64);
        assert_eq!(SymbolSet::parse("quad"), Some(SymbolSet::Quadrants));
        assert_eq!(SymbolSet::parse("oc"), None);
    }

    #[test]
    fn the_palette_searches_find_the_nearest() {
        for v in 0..=255u8 {
            let near = (0..6)
                .min_by_key(|&i| (CUBE[i] as i32 - v as i32).abs())
                .unwrap();
            assert_eq!(CUBE_LEVEL[v as usize] as usize, near, "{v}");
        }
        for c in [
            [0, 0, 0],
            [100, 100, 100],
            [205, 0, 0],
            [128, 64, 200],
            [255; 3],
        ] {
            let near = (0..16).min_by_key(|&i| dist(c, ANSI16[i])).unwrap();
            assert_eq!(ansi16(c) as usize, near, "{c:?}");
        }
    }

    #[test]
    fn colours_at_each_depth() {
        assert_eq!(palette256([0, 0, 0]), 16);
        assert_eq!(palette256([255, 255, 255]), 231);
        assert_eq!(palette256([128, 128, 128]), 244);
        assert_eq!(palette256_rgb(palette256([95, 135, 175])), [95, 135, 175]);
        let s = Symbols {
            cols: 2,
            rows: 1,
            set: SymbolSet::Half,
            cells: vec![
                Cell {
                    symbol: '▀',
                    fg: [255, 0, 0],
                    bg: [0, 0, 0],
                },
                Cell {
                    symbol: ' ',
                    fg: [0, 0, 0],
                    bg: [0, 0, 0],
                },
            ],
        };
        assert_eq!(
            s.ansi(Depth::True),
            "\x1b[48;2;0;0;0m\x1b[38;2;255;0;0m▀ \x1b[0m\n"
        );
        assert_eq!(
            s.ansi(Depth::C256),
            "\x1b[48;5;16m\x1b[38;5;196m▀ \x1b[0m\n"
        );
        assert_eq!(s.ansi(Depth::C16), "\x1b[40m\x1b[91m▀ \x1b[0m\n");
    }

    /// A frame of `w` × `h` from a colour function.
    /// A `w` × `h` black frame with a `colour` square of pixels 1 and 2 each
    /// way (a point in the middle of a 4 × 4 sub-cell at the corner).
    fn point(w: u32, h: u32, colour: Colour) -> Vec<u8> {
        frame(w, h, |x, y| {
            if (1..3).contains(&x) && (1..3).contains(&y) {
                colour
            } else {
                [0; 3]
            }
        })
    }

    fn frame(w: u32, h: u32, f: impl Fn(u32, u32) -> Colour) -> Vec<u8> {
        let mut v = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let [r, g, b] = f(x, y);
                v.extend_from_slice(&[r, g, b, 255]);
            }
        }
        v
    }

    /// A half-block cell's upper and lower pixel.
    fn halves(c: &Cell) -> (Colour, Colour) {
        match c.symbol {
            ' ' => (c.bg, c.bg),
            '▀' => (c.fg, c.bg),
            other => panic!("not a half block: {other}"),
        }
    }

    fn rgba(w: u32, h: u32, px: &[u8]) -> Rgba<'_> {
        Rgba {
            width: w,
            height: h,
            rgba: px,
        }
    }

    #[test]
    fn two_pixels_a_cell_are_taken_as_they_are() {
        let px = frame(3, 4, |x, y| [x as u8 * 50, y as u8 * 60, 7]);
        let s = Symbols::of(&rgba(3, 4, &px), 3, 2, SymbolSet::Half);
        assert_eq!(s.cells.len(), 6);
        assert_eq!(halves(&s.cells[0]), ([0, 0, 7], [0, 60, 7]));
        assert_eq!(halves(&s.cells[5]), ([100, 120, 7], [100, 180, 7]));
    }

    #[test]
    fn a_larger_frame_is_averaged_and_a_thin_line_survives() {
        // 40×40 black with one white column at x = 13: over 4×2 half-block
        // cells each pixel covers 10×10 frame pixels, so the line shows as a
        // tenth of white (sampling one pixel in ten would lose it): 25.5,
        // truncated as chafa truncates.
        let px = frame(40, 40, |x, _| if x == 13 { [255; 3] } else { [0; 3] });
        let s = Symbols::of(&rgba(40, 40, &px), 4, 2, SymbolSet::Half);
        assert_eq!(halves(&s.cells[1]), ([25; 3], [25; 3]));
        assert_eq!(halves(&s.cells[0]), ([0; 3], [0; 3]));
        // In quadrants, the line's cell is lit on its left half only.
        let q = Symbols::of(&rgba(40, 40, &px), 4, 2, SymbolSet::Quadrants);
        assert_eq!(
            (q.cells[1].symbol, q.cells[1].fg, q.cells[1].bg),
            ('▌', [51; 3], [0; 3])
        );
    }

    #[test]
    fn sextants_weigh_their_rows_as_a_16_pixel_cell_draws_them() {
        // One 8×16 cell: sextant rows are 5, 5 and 6 pixels (as terminals
        // split 16 by thirds). Rows 0–4 black, 5–9 at 60, 10–15 at 119. Each
        // row counted once, lighting the middle and bottom rows together
        // would be best (error ½·59² against ½·60²); weighed by the pixels
        // each row covers, lighting the bottom row alone is (9,000 against
        // 30/11·59² ≈ 9,494), and the colours are the rows' own.
        let px = frame(8, 16, |_, y| match y {
            0..=4 => [0; 3],
            5..=9 => [60; 3],
            _ => [119; 3],
        });
        let s = Symbols::of(&rgba(8, 16, &px), 1, 1, SymbolSet::Sextants);
        let c = s.cells[0];
        assert_eq!(
            Some(c.symbol),
            SymbolSet::Sextants.symbol(0b11_0000),
            "{c:?}"
        );
        assert_eq!((c.fg, c.bg), ([119; 3], [30; 3]));
    }

    #[test]
    fn a_frame_of_more_than_2_24_pixels_a_cell_is_averaged_without_overflow() {
        // 4,100 × 8,200 pixels into one half-block cell: 4,100² (16.8 M)
        // frame pixels a sub-pixel, past the 2^24 whose sums of 255 fit in
        // u32, so the frame is halved first.
        let (w, h) = (4100u32, 8200u32);
        let mut px = vec![255u8; (w * h * 4) as usize];
        // The bottom half at 100: the bottom sub-pixel's mean.
        px[(w * h * 2) as usize..].fill(100);
        let s = Symbols::of(&rgba(w, h, &px), 1, 1, SymbolSet::Half);
        assert_eq!(halves(&s.cells[0]), ([255; 3], [100; 3]));
    }

    #[test]
    fn a_smaller_frame_is_enlarged_and_odd_sizes_cover_every_pixel() {
        let px = frame(2, 2, |x, y| [(x * 100 + y * 10) as u8, 0, 0]);
        let s = Symbols::of(&rgba(2, 2, &px), 4, 2, SymbolSet::Half);
        assert_eq!(halves(&s.cells[0]).0, [0, 0, 0]);
        assert_eq!(halves(&s.cells[3]).0, [100, 0, 0]);
        assert_eq!(halves(&s.cells[7]).1, [110, 0, 0]);
        // 7×5 into 3×2 cells: no panic, every cell set from the frame.
        let px = frame(7, 5, |_, _| [9, 9, 9]);
        for set in SymbolSet::ALL {
            let s = Symbols::of(&rgba(7, 5, &px), 3, 2, set);
            assert!(s.cells.iter().all(|c| c.symbol == ' ' && c.bg == [9; 3]));
        }
        // Nothing to draw: black cells, no panic.
        let s = Symbols::of(&rgba(0, 0, &[]), 3, 2, SymbolSet::Octants);
        assert_eq!(s.cells.len(), 6);
        // The palettes too, braille in 16 colours (chosen from the frame's
        // own pixels) included: a frame smaller than the grid, and none.
        let px = frame(3, 2, |x, _| [(x * 120) as u8, 60, 0]);
        for depth in [Depth::C256, Depth::C16] {
            for set in SymbolSet::ALL {
                let s = Symbols::of_depth(&rgba(3, 2, &px), 5, 4, set, depth);
                assert_eq!(s.cells.len(), 20, "{set:?} {depth:?}");
                assert!(s.cells.iter().any(|c| c.bg != [0; 3] || c.fg != [0; 3]));
                let s = Symbols::of_depth(&rgba(0, 0, &[]), 3, 2, set, depth);
                assert!(s.cells.iter().all(|c| c.bg == [0; 3]), "{set:?} {depth:?}");
            }
        }
    }

    #[test]
    fn colours_are_written_only_when_they_change() {
        let cell = |symbol, fg, bg| Cell { symbol, fg, bg };
        let s = Symbols {
            cols: 3,
            rows: 1,
            set: SymbolSet::Half,
            cells: vec![
                cell('▀', [1, 2, 3], [4, 5, 6]),
                cell('▀', [1, 2, 3], [4, 5, 6]),
                cell(' ', [4, 5, 6], [4, 5, 6]),
            ],
        };
        assert_eq!(
            s.ansi(Depth::True),
            "\x1b[48;2;4;5;6m\x1b[38;2;1;2;3m▀▀ \x1b[0m\n"
        );
    }

    #[test]
    fn the_text_style_follows_the_terminal() {
        let c = |names: &[&str], term, colorterm, features, tmux| {
            let t = choose_text(names, term, colorterm, features, tmux);
            (t.set, t.depth)
        };
        use Depth::*;
        use SymbolSet::*;
        // tmux passes 24-bit colour on only with the RGB feature.
        assert_eq!(
            c(&[], Some("screen-256color"), None, Some("256,title"), true),
            (Quadrants, C256)
        );
        assert_eq!(
            c(
                &[],
                Some("screen-256color"),
                Some("truecolor"),
                Some("256,RGB,title"),
                true
            ),
            (Quadrants, True)
        );
        assert_eq!(
            c(&[], Some("screen"), None, Some("title"), true),
            (Quadrants, C16)
        );
        assert_eq!(
            c(
                &["xterm-kitty"],
                Some("screen-256color"),
                None,
                Some("RGB"),
                true
            ),
            (Sextants, True)
        );
        // Outside tmux: COLORTERM, then the name, then TERM.
        assert_eq!(
            c(
                &["xterm-256color"],
                Some("xterm-256color"),
                Some("truecolor"),
                None,
                false
            ),
            (Quadrants, True)
        );
        assert_eq!(
            c(
                &["xterm-256color"],
                Some("xterm-256color"),
                None,
                None,
                false
            ),
            (Quadrants, C256)
        );
        assert_eq!(
            c(&["kitty(0.26.5)"], Some("xterm-kitty"), None, None, false),
            (Sextants, True)
        );
        assert_eq!(
            c(&["vt100"], Some("vt100"), None, None, false),
            (Quadrants, C16)
        );
    }

    #[test]
    fn truecolor_output_is_pinned() {
        // The 24-bit text of a synthetic frame in every set, hashed (FNV-1a)
        // as the encoder writes it since means are truncated and sub-cells
        // weighed by the pixels they cover (97×61 over 23×9 cells divides
        // unevenly): a change to the fit or to dithering must not move 24-bit
        // output unnoticed, byte for byte.
        let px = frame(97, 61, |x, y| {
            let ring = ((x as i32 - 40).pow(2) + (y as i32 - 30).pow(2)) % 97;
            [(x * 255 / 96) as u8, (y * 4) as u8, (ring * 2) as u8]
        });
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for set in SymbolSet::ALL {
            let s = Symbols::of(&rgba(97, 61, &px), 23, 9, set);
            for b in s.ansi(Depth::True).bytes() {
                h = (h ^ b as u64).wrapping_mul(0x100_0000_01b3);
            }
        }
        eprintln!("truecolor hash {h:#x}");
        assert_eq!(h, 0xdff6_1960_b2d2_684b);
    }

    /// The sub-pixels of `s` as drawn: each cell's pattern in its colours
    /// (`cols·w` × `rows·h`, row by row); a braille dot is a quarter of its
    /// sub-pixel, so a lit one is a quarter foreground and three quarters
    /// background.
    fn drawn_back(s: &Symbols) -> Vec<Colour> {
        let (gw, gh) = s.set.grid();
        let w = s.cols as usize * gw;
        let mut out = vec![[0u8; 3]; w * s.rows as usize * gh];
        let glyphs = s.set.glyphs();
        for (i, cell) in s.cells.iter().enumerate() {
            let p = glyphs
                .iter()
                .position(|g| *g == Some(cell.symbol))
                .unwrap_or_else(|| panic!("{} draws no {:?}", s.set, cell.symbol));
            let (c, r) = (i % s.cols as usize, i / s.cols as usize);
            for j in 0..gw * gh {
                let colour = match (p >> j & 1 == 1, s.set) {
                    (false, _) => cell.bg,
                    (true, SymbolSet::Braille) => {
                        [0, 1, 2].map(|k| ((cell.fg[k] as u16 + 3 * cell.bg[k] as u16) / 4) as u8)
                    }
                    (true, _) => cell.fg,
                };
                out[(r * gh + j / gw) * w + c * gw + j % gw] = colour;
            }
        }
        out
    }

    /// The mean colour error over blocks of `bw` × `bh` sub-pixels: how far
    /// the picture seen from a little way off is from the frame's.
    fn block_error(a: &[Colour], b: &[Colour], w: usize, bw: usize, bh: usize) -> f64 {
        let h = a.len() / w;
        let (mut total, mut blocks) = (0f64, 0usize);
        for by in (0..h - bh + 1).step_by(bh) {
            for bx in (0..w - bw + 1).step_by(bw) {
                let mut d = [0f64; 3];
                for y in by..by + bh {
                    for x in bx..bx + bw {
                        for (k, dk) in d.iter_mut().enumerate() {
                            *dk += a[y * w + x][k] as f64 - b[y * w + x][k] as f64;
                        }
                    }
                }
                let n = (bw * bh) as f64;
                total += d.iter().map(|v| (v / n).powi(2)).sum::<f64>().sqrt();
                blocks += 1;
            }
        }
        total / blocks as f64
    }

    /// Gradients across the frame: grey, and red to blue.
    fn gradients() -> Vec<(&'static str, Vec<u8>)> {
        vec![
            ("grey", frame(240, 96, |x, _| [(x * 255 / 239) as u8; 3])),
            (
                "red to blue",
                frame(240, 96, |x, y| {
                    [
                        (255 - x * 255 / 239) as u8,
                        (y * 2) as u8,
                        (x * 255 / 239) as u8,
                    ]
                }),
            ),
        ]
    }

    #[test]
    fn dithering_draws_a_gradient_closer_than_the_nearest_colours() {
        for (name, px) in gradients() {
            let f = rgba(240, 96, &px);
            for set in SymbolSet::ALL {
                let (gw, gh) = set.grid();
                let (cols, rows) = (60, 24);
                let want = box_filter(&f, cols * gw, rows * gh);
                let w = cols * gw;
                for depth in [Depth::C16, Depth::C256] {
                    // Before: the 24-bit cells, each colour to the nearest.
                    let mut nearest = Symbols::of(&f, cols as u16, rows as u16, set);
                    for c in &mut nearest.cells {
                        c.fg = quantize(c.fg, depth);
                        c.bg = quantize(c.bg, depth);
                    }
                    let dithered = Symbols::of_depth(&f, cols as u16, rows as u16, set, depth);
                    // Seen over 4 × 2 cells.
                    let (bw, bh) = (4 * gw, 2 * gh);
                    let before = block_error(&drawn_back(&nearest), &want, w, bw, bh);
                    let after = block_error(&drawn_back(&dithered), &want, w, bw, bh);
                    eprintln!("{name} {set} {depth:?}: {before:.2} → {after:.2}");
                    // 16 colours leave wide bands (a quarter off at least);
                    // the 256 palette's are narrow.
                    let gain = if depth == Depth::C16 { 0.75 } else { 1.0 };
                    assert!(
                        after < before * gain,
                        "{name} {set} {depth:?}: {before} → {after}"
                    );
                }
            }
        }
    }

    #[test]
    fn dithered_output_is_one_symbol_a_cell_in_palette_colours() {
        for (name, px) in gradients() {
            let f = rgba(240, 96, &px);
            for set in SymbolSet::ALL {
                for depth in [Depth::C16, Depth::C256] {
                    let s = Symbols::of_depth(&f, 37, 11, set, depth);
                    let text = s.ansi(depth);
                    let lines: Vec<&str> = text.lines().collect();
                    assert_eq!(lines.len(), 11, "{name} {set} {depth:?}");
                    for line in lines {
                        let line = line.strip_suffix("\x1b[0m").expect("reset at the end");
                        let mut cells = 0;
                        let mut chars = line.chars();
                        while let Some(c) = chars.next() {
                            if c != '\x1b' {
                                assert!(set.glyphs().contains(&Some(c)), "{set}: {c:?}");
                                cells += 1;
                                continue;
                            }
                            assert_eq!(chars.next(), Some('['));
                            let seq: String = chars.by_ref().take_while(|&d| d != 'm').collect();
                            let v: Vec<u32> = seq.split(';').map(|p| p.parse().unwrap()).collect();
                            match depth {
                                Depth::C256 => {
                                    assert!(matches!(v[..], [38 | 48, 5, 16..=255]), "{seq}")
                                }
                                _ => assert!(
                                    matches!(v[..], [30..=37 | 40..=47 | 90..=97 | 100..=107]),
                                    "{seq}"
                                ),
                            }
                        }
                        assert_eq!(cells, 37, "{name} {set} {depth:?}");
                    }
                    // Every colour is a palette colour, written as it is.
                    for c in &s.cells {
                        assert_eq!(quantize(c.fg, depth), c.fg);
                        assert_eq!(quantize(c.bg, depth), c.bg);
                    }
                }
            }
        }
    }

    #[test]
    fn dark_share_counts_black_blocks_not_black_pixels() {
        // 8 × 8 pixels as one output pixel: four blocks of 4 × 4. One lit
        // pixel keeps its block from being black; so do lit pixels spread
        // over a block, but faint ones (a mean of at most 2) do not.
        let one = frame(
            8,
            8,
            |x, y| if (x, y) == (1, 1) { [255; 3] } else { [0; 3] },
        );
        assert_eq!(dark_share(&rgba(8, 8, &one), 1, 1), vec![0.75]);
        let faint = frame(8, 8, |x, y| {
            if x < 4 && y < 4 && x == y {
                [8; 3]
            } else {
                [0; 3]
            }
        });
        assert_eq!(dark_share(&rgba(8, 8, &faint), 1, 1), vec![1.0]);
        // A frame of the output's size: each pixel is its own block.
        let px = frame(2, 1, |x, _| [x as u8 * 3; 3]);
        assert_eq!(dark_share(&rgba(2, 1, &px), 2, 1), vec![1.0, 0.0]);
        // Spans of 6 pixels: blocks of 4 and then 2.
        let px = frame(6, 6, |x, y| if x >= 4 && y < 4 { [50; 3] } else { [0; 3] });
        assert_eq!(dark_share(&rgba(6, 6, &px), 1, 1), vec![28.0 / 36.0]);
    }

    #[test]
    fn sparse_points_on_black_stay_black_and_dim_areas_stay_lit() {
        // One cell of half blocks over 8 × 16 pixels. Above, a speck of 4 × 2
        // grey pixels on black: a mean of 5, nearer grey 8 than black, but
        // SSIM sees a haze of grey 8 over the black around the speck.
        let speck = frame(8, 16, |x, y| if x < 4 && y < 2 { [40; 3] } else { [0; 3] });
        let s = Symbols::of_depth(&rgba(8, 16, &speck), 1, 1, SymbolSet::Half, Depth::C256);
        assert_eq!(halves(&s.cells[0]), ([0; 3], [0; 3]));
        // The same mean spread evenly: an area of dim grey, drawn in the
        // darkest grey rather than lost to black.
        let dim = frame(8, 16, |_, y| if y < 8 { [5; 3] } else { [0; 3] });
        let s = Symbols::of_depth(&rgba(8, 16, &dim), 1, 1, SymbolSet::Half, Depth::C256);
        assert_eq!(halves(&s.cells[0]), ([8; 3], [0; 3]));
    }

    #[test]
    fn dim_texture_in_16_colours_is_drawn_as_braille_dots() {
        // Dim brown texture (luma 22 and 11) with no black in it: the nearest
        // of the 16 colours is black for both, which SSIM scores as far from
        // the picture as can be. A bright red dot (a quarter of its
        // sub-pixel) over black shows luma 19.
        let px = frame(8, 16, |x, y| {
            if (x / 4 + y / 4) % 2 == 0 {
                [30, 22, 0]
            } else {
                [15, 11, 0]
            }
        });
        let s = Symbols::of_depth(&rgba(8, 16, &px), 1, 1, SymbolSet::Braille, Depth::C16);
        let c = s.cells[0];
        // Red 205 rather than 255 (luma 15 against 19 a sub-pixel): a dot
        // on an even sub-pixel is contrast the frame lacks, which SSIM
        // counts against the brighter one more (`by_synthesis`).
        assert_eq!((c.fg, c.bg), ([205, 0, 0], [0; 3]), "{c:?}");
        // The dots are the brighter sub-pixels: dots 1 and 3 (left, rows 0
        // and 2), 5 and 8 (right, rows 1 and 3): U+2800 + 0x95.
        assert_eq!(c.symbol, '⢕', "{c:?}");
        // Half blocks cannot mix red with black: black it is.
        let s = Symbols::of_depth(&rgba(8, 16, &px), 1, 1, SymbolSet::Half, Depth::C16);
        assert_eq!(halves(&s.cells[0]), ([0; 3], [0; 3]));
    }

    #[test]
    fn sub_stat_measures_the_middle_and_the_ring() {
        // 4 × 4 pixels, grey 100 in the middle 2 × 2 and black around it.
        let px = point(4, 4, [100; 3]);
        let s = sub_stat(&rgba(4, 4, &px), (0, 4), (0, 4));
        assert_eq!((s.mu, s.m_in, s.m_out), (25.0, 100.0, 0.0));
        assert!((s.var - 1875.0).abs() < 0.01, "{s:?}");
        // A single pixel is all middle.
        let s = sub_stat(&rgba(4, 4, &px), (1, 2), (1, 2));
        assert_eq!((s.mu, s.var, s.m_in, s.m_out), (100.0, 0.0, 100.0, 100.0));
    }

    #[test]
    fn braille_in_16_colours_draws_a_point_where_it_lies() {
        // A white point of 2 × 2 pixels in the middle of the upper left
        // sub-cell of a black 8 × 16 cell: dot 1 in white.
        let px = point(8, 16, [255; 3]);
        let s = Symbols::of_depth(&rgba(8, 16, &px), 1, 1, SymbolSet::Braille, Depth::C16);
        let c = s.cells[0];
        // (In grey 127, not white: white costs too much as a flat colour
        // to be among the colours tried; adding the colour a dot needs to
        // show the brightest sub-cell lowered airborne braille by 0.001.)
        assert_eq!((c.symbol, c.bg), ('⠁', [0; 3]), "{c:?}");
        assert!(luma(c.fg) > 100.0, "{c:?}");
    }

    #[test]
    fn sparse_points_in_16_colours_are_drawn_closer_than_the_fit_draws_them() {
        // A cell of the building bench frame: single amber points (luma 178)
        // scattered over black, about one pixel in five, sub-pixel means of
        // luma 25–52. The per-group fit puts bright dots where those means
        // are highest: structure the frame does not have, with black between
        // them where the frame's local mean is lit. Chosen by its pixels,
        // the cell is dimmer dots nearly everywhere.
        const ROWS: [&str; 16] = [
            ".#..#...", ".#.....#", "....#...", ".#.....#", "....#..#", ".#..#...", ".#.....#",
            "....#...", "#......#", "...#....", ".#....#.", "....#..#", "#..#....", "......#.",
            "..#..#..", "#......#",
        ];
        let px = frame(8, 16, |x, y| {
            if ROWS[y as usize].as_bytes()[x as usize] == b'#' {
                [245, 180, 0]
            } else {
                [0; 3]
            }
        });
        let f = rgba(8, 16, &px);
        let s = Symbols::of_depth(&f, 1, 1, SymbolSet::Braille, Depth::C16);
        let ours = cell_ssim(&px, &s.cells[0]);
        // The per-group fit of the same cell (as braille in 256 colours
        // still is): dots where the sub-pixel means are highest.
        let sub = box_filter(&f, 2, 4);
        let dark = dark_share(&f, 2, 4);
        let table = SymbolSet::Braille.table();
        let (p, fg, bg) = fit_quantized(&sub, &dark[..].try_into().unwrap(), table, Depth::C16);
        let fit = Cell {
            symbol: table.glyphs[p].unwrap(),
            fg,
            bg,
        };
        let theirs = cell_ssim(&px, &fit);
        // (0.10 against −0.06 when written.)
        assert!(
            ours > theirs + 0.1,
            "{:?} {ours} against {fit:?} {theirs}",
            s.cells[0]
        );
    }

    /// SSIM of luma (11 × 11 Gaussian, σ 1.5, edges repeated) between an
    /// 8 × 16 frame and a braille cell drawn over it as `text_quality`
    /// draws it: a dot is the middle half of its 4 × 4 sub-cell each way.
    fn cell_ssim(frame: &[u8], cell: &Cell) -> f32 {
        let p = (0..256)
            .find(|&p| SymbolSet::Braille.symbol(p) == Some(cell.symbol))
            .unwrap();
        let (mut a, mut b) = (vec![0f32; 128], vec![0f32; 128]);
        for y in 0..16 {
            for x in 0..8 {
                let i = y * 8 + x;
                a[i] = luma([frame[i * 4], frame[i * 4 + 1], frame[i * 4 + 2]]);
                let on = p >> ((y / 4) * 2 + x / 4) & 1 == 1
                    && (1..3).contains(&(x % 4))
                    && (1..3).contains(&(y % 4));
                b[i] = luma(if on { cell.fg } else { cell.bg });
            }
        }
        let k: Vec<f32> = (-5..=5i32).map(|i| (-(i * i) as f32 / 4.5).exp()).collect();
        let blur = |v: &[f32]| {
            let mut o = vec![0f32; 128];
            for y in 0..16i32 {
                for x in 0..8i32 {
                    let (mut s, mut n) = (0f32, 0f32);
                    for (dy, ky) in (-5..=5).zip(&k) {
                        for (dx, kx) in (-5..=5).zip(&k) {
                            let (yy, xx) = ((y + dy).clamp(0, 15), (x + dx).clamp(0, 7));
                            s += ky * kx * v[(yy * 8 + xx) as usize];
                            n += ky * kx;
                        }
                    }
                    o[(y * 8 + x) as usize] = s / n;
                }
            }
            o
        };
        let prod = |p: &[f32], q: &[f32]| p.iter().zip(q).map(|(x, y)| x * y).collect::<Vec<_>>();
        let (ma, mb) = (blur(&a), blur(&b));
        let (saa, sbb, sab) = (
            blur(&prod(&a, &a)),
            blur(&prod(&b, &b)),
            blur(&prod(&a, &b)),
        );
        (0..128)
            .map(|i| {
                let (mx, my) = (ma[i], mb[i]);
                let (vx, vy, cxy) = (saa[i] - mx * mx, sbb[i] - my * my, sab[i] - mx * my);
                ((2.0 * mx * my + C1) * (2.0 * cxy + C2))
                    / ((mx * mx + my * my + C1) * (vx + vy + C2))
            })
            .sum::<f32>()
            / 128.0
    }

    #[test]
    fn braille_in_16_colours_passes_on_the_error_of_the_dots_as_they_show() {
        // Dim brown between the palette's colours, over 12 × 6 cells: what
        // the cells show (a dot a quarter of its sub-pixel) averages near
        // the frame's luma. Counting dots as whole sub-pixels, the error
        // passed on says the cells are brighter than they show, and the
        // whole draws far too dark.
        let colour = [60, 44, 0];
        let px = frame(96, 96, |_, _| colour);
        let s = Symbols::of_depth(&rgba(96, 96, &px), 12, 6, SymbolSet::Braille, Depth::C16);
        let shown: f32 = s
            .cells
            .iter()
            .map(|c| {
                let p = (0..256)
                    .find(|&p| SymbolSet::Braille.symbol(p) == Some(c.symbol))
                    .unwrap();
                let k = (p as u32).count_ones() as f32 / 8.0 * 0.25;
                luma(c.fg) * k + luma(c.bg) * (1.0 - k)
            })
            .sum::<f32>()
            / s.cells.len() as f32;
        // (Half the error is passed on, not all of it: 36.7 against 43.8
        // when written, and 18.5 with dots counted whole.)
        assert!(
            (shown - luma(colour)).abs() < 10.0,
            "{shown} against {}",
            luma(colour)
        );
    }

    #[test]
    fn flat_palette_colours_stay_flat() {
        // All black, and a palette colour of each depth: no dither noise.
        for (colour, depth) in [
            ([0, 0, 0], Depth::C16),
            ([0, 0, 0], Depth::C256),
            ([205, 0, 0], Depth::C16),
            ([95, 135, 175], Depth::C256),
            ([118, 118, 118], Depth::C256),
        ] {
            let px = frame(50, 30, |_, _| colour);
            for set in SymbolSet::ALL {
                let s = Symbols::of_depth(&rgba(50, 30, &px), 13, 7, set, depth);
                assert!(
                    s.cells.iter().all(|c| c.symbol == ' ' && c.bg == colour),
                    "{colour:?} {set} {depth:?}"
                );
            }
        }
    }

    #[test]
    fn dithering_is_deterministic_and_24_bit_is_not_dithered() {
        let (_, px) = gradients().remove(1);
        let f = rgba(240, 96, &px);
        for set in SymbolSet::ALL {
            for depth in [Depth::C16, Depth::C256] {
                let a = Symbols::of_depth(&f, 41, 13, set, depth);
                assert_eq!(a, Symbols::of_depth(&f, 41, 13, set, depth));
                assert_eq!(
                    a.ansi(depth),
                    Symbols::of_depth(&f, 41, 13, set, depth).ansi(depth)
                );
            }
            assert_eq!(
                Symbols::of_depth(&f, 41, 13, set, Depth::True),
                Symbols::of(&f, 41, 13, set)
            );
        }
    }
}
