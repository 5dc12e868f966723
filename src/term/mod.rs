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
pub use inline::{Protocol, print_frame, terminal_pixels};
