//! pcimg: massive point clouds stored as multi-band image pyramids (Du & Li 2009),
//! viewed from the terminal.
//!
//! Data flows one way: [`ingest`] (input readers) → [`store`] (the image format) →
//! level selection and loading → renderers → the terminal interface.

pub mod points;
pub mod render;
pub mod store;
pub mod text;
