//! Terminal graphics: which inline image protocol to use, printing a frame inline
//! (kitty, sixel, iTerm2, or Unicode half-blocks), and our own sixel encoder.

pub mod inline;
pub mod palette;
pub mod sixel;

pub use inline::{Protocol, print_frame, terminal_pixels};
