//! Terminal graphics: finding out what the terminal draws (asking it, or the tmux
//! server), printing a frame inline (kitty, sixel, iTerm2, or text: Unicode symbols in
//! colour), and our own sixel, kitty and text encoders.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

use pcimg_core::text;

pub mod detect;
pub mod inline;
pub mod kitty;
pub mod palette;
pub mod probe;
pub(crate) mod replies;
pub mod sixel;
pub mod symbols;
pub mod tmux;
pub mod typed;

pub use detect::{Detection, Graphics, TerminalEnv, detect};
pub use inline::{Protocol, print_frame};

/// An RGBA8 picture, row by row: what every encoder here draws. This crate knows
/// no renderer: a caller lends its frame's pixels as one.
#[derive(Debug, Clone, Copy)]
pub struct Rgba<'a> {
    pub width: u32,
    pub height: u32,
    /// `width × height × 4` bytes.
    pub rgba: &'a [u8],
}

/// A picture of `w` × `h` pixels whose bytes count 0..250 over and over (tests;
/// its pixels live as long as the test process).
#[cfg(test)]
pub(crate) fn test_frame(w: u32, h: u32) -> Rgba<'static> {
    let rgba = (0..w * h * 4).map(|i| (i % 251) as u8).collect::<Vec<u8>>();
    Rgba {
        width: w,
        height: h,
        rgba: Vec::leak(rgba),
    }
}
