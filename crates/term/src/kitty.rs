//! Kitty graphics: frames sent as zlib-compressed RGB and shown at a given size in
//! cells (so a frame rendered at reduced resolution is scaled up by the terminal),
//! either placed at the cursor or as a virtual placement drawn by Unicode
//! placeholder cells (U+10EEEE with row and column diacritics), which is what
//! works inside tmux: tmux keeps the placeholder cells like any text and passes
//! the image itself through to the outer terminal.

use crate::Rgba;
use std::io::Write as _;

/// The character kitty reserves for image placeholders.
pub const PLACEHOLDER: char = '\u{10EEEE}';

/// Base64 characters per chunk (the protocol's limit).
const CHUNK: usize = 4096;

/// How a frame is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Placement {
    pub id: u32,
    pub cols: u16,
    pub rows: u16,
    /// A virtual placement shown by placeholder cells (`U=1`), else at the cursor.
    pub placeholders: bool,
    /// Each chunk wrapped in tmux passthrough.
    pub passthrough: bool,
    /// A placement at the cursor drawn below text and below cells with a
    /// background colour ([`BELOW_TEXT`]), so text written over it shows (the
    /// inspector's overlays); else above text, kitty's default.
    pub below_text: bool,
}

/// The z-index that puts an image under text and under cells with a
/// non-default background (kitty draws those above images whose z-index is
/// below −1,073,741,824).
pub const BELOW_TEXT: i64 = -1_073_741_825;

/// The escape sequences that send `frame` (alpha dropped: `f=24`, deflated: `o=z`)
/// and show it over `cols` × `rows` cells, whatever its pixel size.
pub fn transmit(frame: &Rgba<'_>, p: Placement) -> String {
    let rgb: Vec<u8> = frame
        .rgba
        .chunks_exact(4)
        .flat_map(|px| [px[0], px[1], px[2]])
        .collect();
    let mut z = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(rgb.len() / 4),
        flate2::Compression::fast(),
    );
    // Writing into a Vec cannot fail.
    let _ = z.write_all(&rgb);
    let packed = z.finish().unwrap_or_default();
    chunked("f=24,o=z", &packed, frame, p)
}

/// [`transmit`] with the frame reduced to at most `colors` colours
/// ([`super::palette`], as sixel frames are) and sent as an indexed PNG
/// (`f=100`): one byte a pixel before deflate instead of three, in runs of one
/// index that deflate well, for a link too slow for the exact frame.
pub fn transmit_indexed(frame: &Rgba<'_>, colors: usize, p: Placement) -> String {
    let image = super::palette::reduce(frame.rgba, colors);
    let png = indexed_png(&image, frame.width, frame.height).unwrap_or_default();
    chunked("f=100", &png, frame, p)
}

/// An indexed image as PNG (8-bit indices, no filter: indices are not
/// gradients, and runs of one index are what deflate finds).
fn indexed_png(image: &super::palette::Indexed, width: u32, height: u32) -> Option<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Indexed);
    enc.set_depth(png::BitDepth::Eight);
    let mut palette: Vec<u8> = image.palette.iter().flatten().copied().collect();
    if palette.is_empty() {
        palette.extend_from_slice(&[0, 0, 0]);
    }
    enc.set_palette(palette);
    enc.set_compression(png::Compression::Balanced);
    enc.set_filter(png::Filter::NoFilter);
    let mut w = enc.write_header().ok()?;
    w.write_image_data(&image.indices).ok()?;
    w.finish().ok()?;
    Some(out)
}

/// `payload` in base64 chunks of [`CHUNK`], the first with the keys that send
/// it as image `p.id` in `format` (`f=…` and how it is packed) and place it.
fn chunked(format: &str, payload: &[u8], frame: &Rgba<'_>, p: Placement) -> String {
    use base64::Engine as _;
    let data = base64::engine::general_purpose::STANDARD.encode(payload);
    let chunks: Vec<&[u8]> = data.as_bytes().chunks(CHUNK).collect();
    let mut seq = String::with_capacity(data.len() + chunks.len() * 32 + 96);
    let n = chunks.len().max(1);
    for i in 0..n {
        let chunk = chunks
            .get(i)
            .and_then(|c| std::str::from_utf8(c).ok())
            .unwrap_or("");
        let more = u8::from(i + 1 < n);
        let mut one = String::with_capacity(chunk.len() + 96);
        if i == 0 {
            let virtual_ = match (p.placeholders, p.below_text) {
                (true, _) => ",U=1".to_string(),
                (false, false) => ",C=1".to_string(),
                (false, true) => format!(",C=1,z={BELOW_TEXT}"),
            };
            one.push_str(&format!(
                "\x1b_Ga=T,q=2,i={},{format},s={},v={},c={},r={}{virtual_},m={more};{chunk}\x1b\\",
                p.id, frame.width, frame.height, p.cols, p.rows
            ));
        } else {
            one.push_str(&format!("\x1b_Gm={more};{chunk}\x1b\\"));
        }
        if p.passthrough {
            seq.push_str(&super::tmux::passthrough(&one));
        } else {
            seq.push_str(&one);
        }
    }
    seq
}

/// The sequence that deletes image `id` and its placements.
pub fn delete(id: u32, passthrough: bool) -> String {
    let s = format!("\x1b_Ga=d,d=I,i={id},q=2\x1b\\");
    if passthrough {
        super::tmux::passthrough(&s)
    } else {
        s
    }
}

/// The foreground colour that names image `id` to placeholder cells (its low 24
/// bits; the high byte goes in a third diacritic).
pub fn id_color(id: u32) -> (u8, u8, u8) {
    let [_, r, g, b] = id.to_be_bytes();
    (r, g, b)
}

/// The text of the placeholder cell at (`row`, `col`) of image `id`. Every cell is
/// explicit (row, column and the id's high byte), so no cell depends on the one
/// before it being drawn.
pub fn placeholder(row: u16, col: u16, id: u32) -> String {
    let mut s = String::with_capacity(12);
    s.push(PLACEHOLDER);
    s.push(diacritic(row));
    s.push(diacritic(col));
    s.push(diacritic(id.to_be_bytes()[0] as u16));
    s
}

/// How many rows and columns placeholders can address.
pub fn max_cells() -> u16 {
    DIACRITICS.len() as u16
}

fn diacritic(n: u16) -> char {
    DIACRITICS.get(n as usize).copied().unwrap_or(DIACRITICS[0])
}

/// Kitty's `rowcolumn-diacritics.txt`: the n-th combining mark stands for n.
static DIACRITICS: [char; 297] = [
    '\u{305}',
    '\u{30D}',
    '\u{30E}',
    '\u{310}',
    '\u{312}',
    '\u{33D}',
    '\u{33E}',
    '\u{33F}',
    '\u{346}',
    '\u{34A}',
    '\u{34B}',
    '\u{34C}',
    '\u{350}',
    '\u{351}',
    '\u{352}',
    '\u{357}',
    '\u{35B}',
    '\u{363}',
    '\u{364}',
    '\u{365}',
    '\u{366}',
    '\u{367}',
    '\u{368}',
    '\u{369}',
    '\u{36A}',
    '\u{36B}',
    '\u{36C}',
    '\u{36D}',
    '\u{36E}',
    '\u{36F}',
    '\u{483}',
    '\u{484}',
    '\u{485}',
    '\u{486}',
    '\u{487}',
    '\u{592}',
    '\u{593}',
    '\u{594}',
    '\u{595}',
    '\u{597}',
    '\u{598}',
    '\u{599}',
    '\u{59C}',
    '\u{59D}',
    '\u{59E}',
    '\u{59F}',
    '\u{5A0}',
    '\u{5A1}',
    '\u{5A8}',
    '\u{5A9}',
    '\u{5AB}',
    '\u{5AC}',
    '\u{5AF}',
    '\u{5C4}',
    '\u{610}',
    '\u{611}',
    '\u{612}',
    '\u{613}',
    '\u{614}',
    '\u{615}',
    '\u{616}',
    '\u{617}',
    '\u{657}',
    '\u{658}',
    '\u{659}',
    '\u{65A}',
    '\u{65B}',
    '\u{65D}',
    '\u{65E}',
    '\u{6D6}',
    '\u{6D7}',
    '\u{6D8}',
    '\u{6D9}',
    '\u{6DA}',
    '\u{6DB}',
    '\u{6DC}',
    '\u{6DF}',
    '\u{6E0}',
    '\u{6E1}',
    '\u{6E2}',
    '\u{6E4}',
    '\u{6E7}',
    '\u{6E8}',
    '\u{6EB}',
    '\u{6EC}',
    '\u{730}',
    '\u{732}',
    '\u{733}',
    '\u{735}',
    '\u{736}',
    '\u{73A}',
    '\u{73D}',
    '\u{73F}',
    '\u{740}',
    '\u{741}',
    '\u{743}',
    '\u{745}',
    '\u{747}',
    '\u{749}',
    '\u{74A}',
    '\u{7EB}',
    '\u{7EC}',
    '\u{7ED}',
    '\u{7EE}',
    '\u{7EF}',
    '\u{7F0}',
    '\u{7F1}',
    '\u{7F3}',
    '\u{816}',
    '\u{817}',
    '\u{818}',
    '\u{819}',
    '\u{81B}',
    '\u{81C}',
    '\u{81D}',
    '\u{81E}',
    '\u{81F}',
    '\u{820}',
    '\u{821}',
    '\u{822}',
    '\u{823}',
    '\u{825}',
    '\u{826}',
    '\u{827}',
    '\u{829}',
    '\u{82A}',
    '\u{82B}',
    '\u{82C}',
    '\u{82D}',
    '\u{951}',
    '\u{953}',
    '\u{954}',
    '\u{F82}',
    '\u{F83}',
    '\u{F86}',
    '\u{F87}',
    '\u{135D}',
    '\u{135E}',
    '\u{135F}',
    '\u{17DD}',
    '\u{193A}',
    '\u{1A17}',
    '\u{1A75}',
    '\u{1A76}',
    '\u{1A77}',
    '\u{1A78}',
    '\u{1A79}',
    '\u{1A7A}',
    '\u{1A7B}',
    '\u{1A7C}',
    '\u{1B6B}',
    '\u{1B6D}',
    '\u{1B6E}',
    '\u{1B6F}',
    '\u{1B70}',
    '\u{1B71}',
    '\u{1B72}',
    '\u{1B73}',
    '\u{1CD0}',
    '\u{1CD1}',
    '\u{1CD2}',
    '\u{1CDA}',
    '\u{1CDB}',
    '\u{1CE0}',
    '\u{1DC0}',
    '\u{1DC1}',
    '\u{1DC3}',
    '\u{1DC4}',
    '\u{1DC5}',
    '\u{1DC6}',
    '\u{1DC7}',
    '\u{1DC8}',
    '\u{1DC9}',
    '\u{1DCB}',
    '\u{1DCC}',
    '\u{1DD1}',
    '\u{1DD2}',
    '\u{1DD3}',
    '\u{1DD4}',
    '\u{1DD5}',
    '\u{1DD6}',
    '\u{1DD7}',
    '\u{1DD8}',
    '\u{1DD9}',
    '\u{1DDA}',
    '\u{1DDB}',
    '\u{1DDC}',
    '\u{1DDD}',
    '\u{1DDE}',
    '\u{1DDF}',
    '\u{1DE0}',
    '\u{1DE1}',
    '\u{1DE2}',
    '\u{1DE3}',
    '\u{1DE4}',
    '\u{1DE5}',
    '\u{1DE6}',
    '\u{1DFE}',
    '\u{20D0}',
    '\u{20D1}',
    '\u{20D4}',
    '\u{20D5}',
    '\u{20D6}',
    '\u{20D7}',
    '\u{20DB}',
    '\u{20DC}',
    '\u{20E1}',
    '\u{20E7}',
    '\u{20E9}',
    '\u{20F0}',
    '\u{2CEF}',
    '\u{2CF0}',
    '\u{2CF1}',
    '\u{2DE0}',
    '\u{2DE1}',
    '\u{2DE2}',
    '\u{2DE3}',
    '\u{2DE4}',
    '\u{2DE5}',
    '\u{2DE6}',
    '\u{2DE7}',
    '\u{2DE8}',
    '\u{2DE9}',
    '\u{2DEA}',
    '\u{2DEB}',
    '\u{2DEC}',
    '\u{2DED}',
    '\u{2DEE}',
    '\u{2DEF}',
    '\u{2DF0}',
    '\u{2DF1}',
    '\u{2DF2}',
    '\u{2DF3}',
    '\u{2DF4}',
    '\u{2DF5}',
    '\u{2DF6}',
    '\u{2DF7}',
    '\u{2DF8}',
    '\u{2DF9}',
    '\u{2DFA}',
    '\u{2DFB}',
    '\u{2DFC}',
    '\u{2DFD}',
    '\u{2DFE}',
    '\u{2DFF}',
    '\u{A66F}',
    '\u{A67C}',
    '\u{A67D}',
    '\u{A6F0}',
    '\u{A6F1}',
    '\u{A8E0}',
    '\u{A8E1}',
    '\u{A8E2}',
    '\u{A8E3}',
    '\u{A8E4}',
    '\u{A8E5}',
    '\u{A8E6}',
    '\u{A8E7}',
    '\u{A8E8}',
    '\u{A8E9}',
    '\u{A8EA}',
    '\u{A8EB}',
    '\u{A8EC}',
    '\u{A8ED}',
    '\u{A8EE}',
    '\u{A8EF}',
    '\u{A8F0}',
    '\u{A8F1}',
    '\u{AAB0}',
    '\u{AAB2}',
    '\u{AAB3}',
    '\u{AAB7}',
    '\u{AAB8}',
    '\u{AABE}',
    '\u{AABF}',
    '\u{AAC1}',
    '\u{FE20}',
    '\u{FE21}',
    '\u{FE22}',
    '\u{FE23}',
    '\u{FE24}',
    '\u{FE25}',
    '\u{FE26}',
    '\u{10A0F}',
    '\u{10A38}',
    '\u{1D185}',
    '\u{1D186}',
    '\u{1D187}',
    '\u{1D188}',
    '\u{1D189}',
    '\u{1D1AA}',
    '\u{1D1AB}',
    '\u{1D1AC}',
    '\u{1D1AD}',
    '\u{1D242}',
    '\u{1D243}',
    '\u{1D244}',
];

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine as _;
    use std::io::Read as _;

    use crate::test_frame as frame;

    fn decode(seq: &str) -> (String, Vec<u8>) {
        let parts: Vec<&str> = seq.split("\x1b\\").filter(|p| !p.is_empty()).collect();
        let head = parts[0].split_once(';').unwrap().0.to_string();
        let data: String = parts.iter().map(|p| p.split_once(';').unwrap().1).collect();
        let packed = base64::engine::general_purpose::STANDARD
            .decode(data)
            .unwrap();
        let mut rgb = Vec::new();
        flate2::read::ZlibDecoder::new(&packed[..])
            .read_to_end(&mut rgb)
            .unwrap();
        (head, rgb)
    }

    /// Image 7 on 20 × 10 cells through placeholders, drawn over text.
    fn placed() -> Placement {
        Placement {
            id: 7,
            cols: 20,
            rows: 10,
            placeholders: true,
            passthrough: false,
            below_text: false,
        }
    }

    #[test]
    fn frames_are_deflated_rgb_scaled_to_their_cells() {
        let f = frame(64, 48);
        let p = placed();
        let (head, rgb) = decode(&transmit(&f, p));
        assert_eq!(
            head,
            "\x1b_Ga=T,q=2,i=7,f=24,o=z,s=64,v=48,c=20,r=10,U=1,m=0"
        );
        let want: Vec<u8> = f.rgba.chunks(4).flat_map(|c| [c[0], c[1], c[2]]).collect();
        assert_eq!(rgb, want);
    }

    #[test]
    fn indexed_frames_are_palette_pngs_of_the_frames_size() {
        // 40 greys in a 64×48 frame, asked for in 8 colours.
        let rgba: Vec<u8> = (0..64 * 48)
            .flat_map(|i| {
                let v = (i % 40 * 6) as u8;
                [v, v, v, 255]
            })
            .collect();
        let f = Rgba {
            width: 64,
            height: 48,
            rgba: &rgba,
        };
        let p = placed();
        let seq = transmit_indexed(&f, 8, p);
        let parts: Vec<&str> = seq.split("\x1b\\").filter(|p| !p.is_empty()).collect();
        assert_eq!(
            parts[0].split_once(';').unwrap().0,
            "\x1b_Ga=T,q=2,i=7,f=100,s=64,v=48,c=20,r=10,U=1,m=0"
        );
        let data: String = parts.iter().map(|p| p.split_once(';').unwrap().1).collect();
        let png = base64::engine::general_purpose::STANDARD
            .decode(data)
            .unwrap();
        let mut dec = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let info = dec.info();
        assert_eq!((info.width, info.height), (64, 48));
        assert_eq!(info.color_type, png::ColorType::Indexed);
        let colours = info.palette.as_ref().unwrap().len() / 3;
        assert!((2..=8).contains(&colours), "{colours} colours");
        let mut buf = vec![0; dec.output_buffer_size().unwrap()];
        dec.next_frame(&mut buf).unwrap();
        assert!(buf.len() >= 64 * 48, "every pixel decodes");
    }

    #[test]
    fn direct_placements_stay_at_the_cursor_and_draw_no_placeholders() {
        // kitty before 0.28: placed at the cursor (`a=T` with no `U`), the cursor
        // left where it was (`C=1`), in chunks of which only the first has keys.
        // Noise, so that even deflated it takes several chunks.
        let mut x = 1u32;
        let noise: Vec<u8> = (0..200 * 100 * 4)
            .map(|_| {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (x >> 24) as u8
            })
            .collect();
        let f = crate::Rgba {
            width: 200,
            height: 100,
            rgba: &noise,
        };
        let p = Placement {
            id: 0x0070_6369,
            cols: 30,
            rows: 12,
            placeholders: false,
            passthrough: false,
            below_text: false,
        };
        let seq = transmit(&f, p);
        let (head, rgb) = decode(&seq);
        assert_eq!(
            head,
            "\x1b_Ga=T,q=2,i=7365481,f=24,o=z,s=200,v=100,c=30,r=12,C=1,m=1"
        );
        let want: Vec<u8> = f.rgba.chunks(4).flat_map(|c| [c[0], c[1], c[2]]).collect();
        assert_eq!(rgb, want);
        assert!(!seq.contains("U=1") && !seq.contains(PLACEHOLDER));
        let chunks: Vec<&str> = seq.split("\x1b\\").filter(|c| !c.is_empty()).collect();
        assert!(chunks.len() > 1);
        for (i, c) in chunks.iter().enumerate().skip(1) {
            let last = i + 1 == chunks.len();
            let keys = if last { "\x1b_Gm=0;" } else { "\x1b_Gm=1;" };
            assert!(c.starts_with(keys), "chunk {i}: {}", &c[..12]);
        }
        assert!(!seq.contains("\x1bPtmux;"));
        // Below text (the inspector writes its overlays over it).
        let below = transmit(
            &f,
            Placement {
                below_text: true,
                ..p
            },
        );
        assert!(
            below.starts_with(
                "\x1b_Ga=T,q=2,i=7365481,f=24,o=z,s=200,v=100,c=30,r=12,C=1,z=-1073741825,m=1;"
            ),
            "{}",
            &below[..80]
        );
    }

    #[test]
    fn passthrough_wraps_every_chunk_and_placeholders_name_the_cell() {
        let f = frame(200, 100); // 60,000 bytes of RGB: several chunks even deflated
        let p = Placement {
            id: 0x0170_6369,
            cols: 4,
            rows: 2,
            placeholders: true,
            passthrough: true,
            below_text: false,
        };
        let seq = transmit(&f, p);
        let wrapped = seq.matches("\x1bPtmux;").count();
        assert!(wrapped >= 1);
        assert_eq!(wrapped, seq.matches("\x1b\x1b_G").count());
        assert_eq!(id_color(p.id), (0x70, 0x63, 0x69));
        let cell: Vec<char> = placeholder(1, 3, p.id).chars().collect();
        assert_eq!(
            cell,
            vec![PLACEHOLDER, DIACRITICS[1], DIACRITICS[3], DIACRITICS[1]]
        );
        assert_eq!(delete(5, false), "\x1b_Ga=d,d=I,i=5,q=2\x1b\\");
    }
}
