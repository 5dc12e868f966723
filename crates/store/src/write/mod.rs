//! The write side: a part's points collected (`builder`), ordered along the Hilbert
//! curve (`hilbert`, `layout`; the paper's row-major order in `paper`), tiled and
//! written atomically (`part`, with its coarse levels `coarse`, tile writer threads
//! `sink` and the output file `out`).

pub mod builder;
pub mod coarse;
pub mod hilbert;
pub mod layout;
pub mod out;
pub mod paper;
pub mod part;
pub mod sink;
