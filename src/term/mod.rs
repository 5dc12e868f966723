//! Terminal graphics: finding out what the terminal draws (asking it, or the tmux
//! server), printing a frame inline (kitty, sixel, iTerm2, or Unicode half-blocks),
//! and our own sixel and kitty encoders.

pub mod detect;
pub mod inline;
pub mod kitty;
pub mod palette;
pub mod probe;
pub mod replies;
pub mod sixel;
pub mod tmux;
pub mod typed;

pub use detect::{Detection, Graphics, TerminalEnv, detect};
pub use inline::{Protocol, print_frame};

/// A frame of `w` × `h` pixels whose bytes count 0..250 over and over (tests).
#[cfg(test)]
pub(crate) fn test_frame(w: u32, h: u32) -> crate::render::Frame {
    crate::render::Frame {
        width: w,
        height: h,
        rgba: (0..w * h * 4).map(|i| (i % 251) as u8).collect(),
        stats: Default::default(),
    }
}
