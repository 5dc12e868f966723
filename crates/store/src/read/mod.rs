//! The read side: opening a part, its headers only (`part`); reading a level or
//! chosen tiles of it into columns (`points`); where the tile bytes come from, a
//! memory map or object storage (`source`, `remote`).

pub mod part;
pub mod points;
#[cfg(feature = "remote")]
mod remote;
mod source;
