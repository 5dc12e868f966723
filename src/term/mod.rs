//! Terminal graphics: which inline image protocol to use, and printing a frame
//! inline (kitty, sixel, iTerm2, or Unicode half-blocks).

pub mod inline;

pub use inline::{Protocol, print_frame, terminal_pixels};
