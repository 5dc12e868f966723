//! pcimg: massive point clouds stored as multi-band image pyramids (Du & Li 2009),
//! viewed from the terminal.
//!
//! Data flows one way: `ingest` (input readers) → [`store`] (the image format) →
//! level selection and loading → renderers → the terminal interface. `convert`
//! drives readers into the store.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]

#[cfg(target_os = "linux")]
pub mod alloc;
/// Elsewhere the system allocator serves everything; the pool's controls do nothing.
#[cfg(not(target_os = "linux"))]
pub mod alloc {
    pub fn set_pool_limit(_bytes: usize) {}
    pub fn release_pool() {}
    pub fn fresh_bytes() -> usize {
        0
    }
}
pub mod bigvec;
pub mod camera;
pub mod cli;
pub mod clock;
pub mod convert;
pub mod ingest;
pub mod lod;
pub mod points;
pub mod remote;
pub mod render;
pub mod store;
pub mod synth;
pub mod synth_formats;
pub mod term;
pub mod text;
pub mod tui;

/// Large blocks are recycled within the process (`alloc`); everything linking the
/// library (the binary, tests, benchmarks) allocates the same way.
#[cfg(target_os = "linux")]
#[global_allocator]
static GLOBAL: alloc::Recycling = alloc::Recycling;
