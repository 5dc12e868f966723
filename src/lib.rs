//! pcimg: massive point clouds stored as multi-band image pyramids (Du & Li 2009),
//! viewed from the terminal.
//!
//! Data flows one way: `ingest` (input readers) → [`store`] (the image format) →
//! level selection and loading → renderers → the terminal interface. `convert`
//! drives readers into the store.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]

pub mod alloc;
pub mod bigvec;
pub mod camera;
pub mod cli;
pub mod convert;
pub mod ingest;
pub mod lod;
pub mod points;
pub mod render;
pub mod store;
pub mod synth;
pub mod term;
pub mod text;
pub mod tui;

/// Large blocks are recycled within the process (`alloc`); everything linking the
/// library (the binary, tests, benchmarks) allocates the same way.
#[global_allocator]
static GLOBAL: alloc::Recycling = alloc::Recycling;
