//! pcimg: massive point clouds stored as multi-band image pyramids (Du & Li 2009),
//! viewed from the terminal. This crate is the binary's body: the commands
//! (`cli`), the inspector (`tui`) and the converter (`convert`), over the
//! workspace's layer crates.
//!
//! Data flows one way: `ingest` (input readers) → [`store`] (the image format) →
//! level selection and loading → renderers → the terminal interface. `convert`
//! drives readers into the store.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

// The layers below the binary, under the names the binary's modules use for them
// (`crate::store::Dataset`, `pcimg::render::Frame`): each is its own crate
// (`crates/`), and the compiler keeps the chain one-way.
pub use pcimg_core::{alloc, bigvec, clock, disk, points, text, time};
pub use pcimg_ingest as ingest;
pub use pcimg_render as render;
pub use pcimg_render::{camera, lod};
pub use pcimg_store as store;
pub use pcimg_store::remote;
pub use pcimg_term as term;

// The binary's own layers: the converter, the inspector, the commands, and the
// advice they give (the libraries' errors carry facts; `advice` words them).
pub mod advice;
pub mod cli;
pub mod convert;
pub mod copc_tiles;
pub mod export;
pub mod stats;
pub mod survey;
pub mod synth;
pub mod synth_formats;
pub mod tui;

/// A rendered frame's pixels as the terminal crate takes a picture.
pub fn pixels(f: &render::Frame) -> term::Rgba<'_> {
    term::Rgba {
        width: f.width,
        height: f.height,
        rgba: &f.rgba,
    }
}

/// Large blocks are recycled within the process (`alloc`); everything linking the
/// library (the binary, tests, benchmarks) allocates the same way.
#[cfg(target_os = "linux")]
#[global_allocator]
static GLOBAL: alloc::Recycling = alloc::Recycling;
