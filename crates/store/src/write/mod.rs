//! The write side: a part's points collected (`builder`), ordered along the Hilbert
//! curve (`hilbert`, `layout`; the paper's row-major order in `paper`), tiled and
//! written atomically (`part`, with its coarse levels `coarse`, tile writer threads
//! `sink` and the output file `out`).

pub(crate) mod builder;
pub(crate) mod coarse;
pub(crate) mod hilbert;
pub mod layout;
pub(crate) mod out;
pub mod paper;
pub(crate) mod part;
pub(crate) mod sink;
