//! The viewpoint, shared by level selection and the renderers: re-exported from
//! the renderer's camera module until it moves here.
pub use crate::render::camera::*;
