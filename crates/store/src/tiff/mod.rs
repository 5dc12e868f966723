//! The TIFF layer: the bounds-checked directory parser and the writer of a part's
//! head (`ifd`), tile payload codecs (`codec`, the fast LERC path `lerc_z`), the
//! image geometry of Z-ordered tiles (`zorder`, `tiles`) and the part's
//! self-description (`metadata`).

pub(crate) mod codec;
pub mod ifd;
mod lerc_z;
pub(crate) mod metadata;
mod runs;
pub(crate) mod tiles;
pub mod zorder;
