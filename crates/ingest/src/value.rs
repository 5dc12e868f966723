//! The column types readers decode into: coordinates as `f64`, attributes as
//! `f32` (or `f64` while attribute offsets are chosen), converted from `f64`.

/// A destination column's value type.
pub trait Val: Copy + Send + Default {
    fn from_f64(v: f64) -> Self;
}

impl Val for f64 {
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v
    }
}

impl Val for f32 {
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}
