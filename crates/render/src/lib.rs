//! Offscreen point renderers: the interface every rasterizer implements
//! ([`Rasterizer`]), the data it consumes ([`PointBatch`], [`RenderOptions`]) and
//! produces ([`Frame`]), and the backend choice ([`create`]).
//!
//! Two rasterizers exist, both built on the same idea (Schütz et al. 2021,
//! "Rendering Point Clouds with Compute Shaders"): every point is transformed,
//! and its packed `depth << 32 | colour` value is merged into a 64-bit
//! framebuffer with a *minimum*, so the nearest point wins without any sorting.
//! A resolve pass turns the packed framebuffer into RGBA8.
//!
//! * [`cpu::CpuRasterizer`]: rayon, per-thread framebuffers merged with `min`.
//! * [`gpu::GpuRasterizer`]: wgpu compute shaders (works on lavapipe/llvmpipe too).
//!
//! ```
//! use pcimg_core::points::Bounds;
//! use pcimg_render::{create, Camera, PointBatch, RenderOptions, RendererChoice};
//!
//! // Two points 637 km east of the datum, stored relative to a per-part origin.
//! let origin = [637_179.22, 5_100_000.0, 300.0];
//! let (x, y, z) = ([0.0f32, 1.0], [0.0f32, 1.0], [0.0f32, 0.5]);
//! let color = [pcimg_render::color::pack_rgb(255, 0, 0); 2];
//! let batch = PointBatch { origin, x: &x, y: &y, z: &z, color: &color };
//! let bounds = Bounds { min: origin, max: [origin[0] + 1.0, origin[1] + 1.0, origin[2] + 0.5] };
//! let camera = Camera::fit(&bounds);
//! let mut renderer = create(RendererChoice::Cpu)?;
//! let opts = RenderOptions { width: 64, height: 48, ..Default::default() };
//! let frame = renderer.render(&camera, &[batch], &opts)?;
//! assert_eq!(frame.rgba.len(), 64 * 48 * 4);
//! assert!(frame.rgba.chunks(4).any(|p| p[0] == 255));
//! # Ok::<(), pcimg_render::RenderError>(())
//! ```
//!
//! Depth convention shared by both: the depth of a point is its positive
//! view-space distance along the view axis (clip-space `w`), stored as the bits of
//! the `f32` (monotonic for positive floats). Ties (same depth bits) are broken
//! by the smaller colour value, so both backends agree exactly.

// Loops over the three axes index several parallel arrays at once.
#![allow(clippy::needless_range_loop)]
#![warn(clippy::undocumented_unsafe_blocks)]

use pcimg_core::{points, text};
use pcimg_store as store;

pub mod camera;
pub mod classes;
pub mod color;
pub mod cpu;
pub mod edl;
pub mod filter;
pub mod font;
pub mod gpu;
pub mod legend;
pub mod lod;
pub(crate) mod marks;
pub mod pick;
pub mod pipeline;
pub mod ramp;
pub mod scene;

pub use camera::{Camera, CameraMode, Containment, Frustum, ViewSpec};
pub use color::ColorMode;

/// The value of an empty framebuffer pixel (no point drew there).
pub const EMPTY_PIXEL: u64 = u64::MAX;

/// Largest accepted frame side, in pixels.
pub const MAX_FRAME_SIDE: u32 = 16384;

/// One set of points sharing an origin: the true position of point `i` is
/// `origin + (x[i], y[i], z[i])`. All four columns must have the same length.
#[derive(Debug, Clone, Copy)]
pub struct PointBatch<'a> {
    pub origin: [f64; 3],
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub z: &'a [f32],
    /// RGBA8 packed little-endian: `r | g << 8 | b << 16` (alpha ignored).
    pub color: &'a [u32],
}

impl PointBatch<'_> {
    /// Number of points, or an error when the columns differ in length.
    pub(crate) fn checked_len(&self) -> Result<usize, RenderError> {
        let n = self.x.len();
        if self.y.len() != n || self.z.len() != n || self.color.len() != n {
            return Err(RenderError::InvalidInput(format!(
                "point batch columns differ in length: x {} y {} z {} color {}",
                n,
                self.y.len(),
                self.z.len(),
                self.color.len()
            )));
        }
        if self.origin.iter().any(|o| !o.is_finite()) {
            return Err(RenderError::InvalidInput(format!(
                "point batch origin is not finite: {:?}",
                self.origin
            )));
        }
        Ok(n)
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// How to draw a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Square splat side in pixels, 1..=3 (other values are clamped).
    pub point_size: u32,
    pub eye_dome_lighting: bool,
    /// Eye-dome lighting's strength and radius (when it is on).
    pub edl: edl::EdlParams,
    pub background: [u8; 3],
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 1280,
            height: 720,
            point_size: 1,
            eye_dome_lighting: false,
            edl: edl::EdlParams::default(),
            background: [0, 0, 0],
        }
    }
}

impl RenderOptions {
    /// Checks the frame size; returns the clamped point size.
    pub fn validate(&self) -> Result<u32, RenderError> {
        if self.width == 0 || self.height == 0 {
            return Err(RenderError::InvalidOptions(format!(
                "frame size must be positive, got {}x{}",
                self.width, self.height
            )));
        }
        if self.width > MAX_FRAME_SIDE || self.height > MAX_FRAME_SIDE {
            return Err(RenderError::InvalidOptions(format!(
                "frame size {}x{} exceeds the maximum side of {MAX_FRAME_SIDE}",
                self.width, self.height
            )));
        }
        Ok(self.point_size.clamp(1, 3))
    }

    /// Width / height.
    pub fn aspect(&self) -> f64 {
        self.width.max(1) as f64 / self.height.max(1) as f64
    }
}

/// Statistics of one rendered frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// Points submitted to the rasterizer (after the caller's culling); each was
    /// transformed, and drawn unless clipped.
    pub points_drawn: u64,
    /// Wall time of the frame, rasterization + resolve + readback, excluding uploads.
    pub render_ms: f64,
    /// Wall time spent uploading point buffers this frame (GPU only; 0 when cached).
    pub upload_ms: f64,
}

/// A rendered image: `rgba` is `width * height * 4` bytes, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
    pub stats: FrameStats,
}

impl Frame {
    /// A frame filled with `background`.
    pub fn background(width: u32, height: u32, background: [u8; 3]) -> Frame {
        let px = [background[0], background[1], background[2], 255];
        Frame {
            width,
            height,
            rgba: px.repeat(width as usize * height as usize),
            stats: FrameStats::default(),
        }
    }

    /// The RGBA of pixel (x, y), or `None` outside the frame.
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 4]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = (y as usize * self.width as usize + x as usize) * 4;
        self.rgba.get(i..i + 4).map(|p| [p[0], p[1], p[2], p[3]])
    }

    /// Saves the frame as a PNG file.
    pub fn save_png(&self, path: &std::path::Path) -> Result<(), RenderError> {
        if self.rgba.len() != self.width as usize * self.height as usize * 4 {
            return Err(RenderError::InvalidInput(format!(
                "frame holds {} bytes, not {}x{}x4",
                self.rgba.len(),
                self.width,
                self.height
            )));
        }
        // Written under a temporary name and renamed: no half-written PNG is left.
        let tmp = png_temporary(path);
        let fail = |e: &dyn std::fmt::Display| {
            let _ = std::fs::remove_file(&tmp);
            RenderError::Io(format!("cannot save {}: {e}", path.display()))
        };
        image::save_buffer_with_format(
            &tmp,
            &self.rgba,
            self.width,
            self.height,
            image::ExtendedColorType::Rgba8,
            image::ImageFormat::Png,
        )
        .map_err(|e| fail(&e))?;
        std::fs::rename(&tmp, path).map_err(|e| fail(&e))
    }
}

/// Where [`Frame::save_png`] writes before renaming to `path`
/// (`.NAME.PID.tmp` beside it): a caller that ends the process on a signal
/// removes it.
pub fn png_temporary(path: &std::path::Path) -> std::path::PathBuf {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

impl From<crate::camera::CameraError> for RenderError {
    fn from(e: crate::camera::CameraError) -> Self {
        RenderError::InvalidOptions(e.0)
    }
}

/// Errors of the renderers.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    #[error("GPU error: {0}")]
    Gpu(String),
    #[error("invalid render options: {0}")]
    InvalidOptions(String),
    #[error("invalid input: {0}")]
    InvalidInput(String),
    #[error("{0}")]
    Io(String),
}

/// An offscreen point rasterizer.
pub trait Rasterizer: Send {
    /// What renders, e.g. `"cpu (2 threads)"` or `"wgpu Vulkan: llvmpipe (LLVM 15...)"`.
    fn name(&self) -> String;
    /// Asks the rasterizer to keep, per pixel, which point won it (for
    /// picking); off by default, since it costs a second projection pass.
    /// Returns whether this rasterizer can (those that cannot are picked by
    /// [`pick::pick`]'s projection).
    fn keep_ids(&mut self, on: bool) -> bool {
        let _ = on;
        false
    }
    /// Per pixel of the last frame, row-major, the [`pick::point_id`] of the
    /// point drawn there ([`pick::NO_POINT`]: none); `None` unless
    /// [`Rasterizer::keep_ids`] was on for that frame.
    fn last_ids(&self) -> Option<&[u64]> {
        None
    }
    /// Draws all batches with `camera` (the camera's aspect is replaced by the
    /// frame's) and returns the image.
    fn render(
        &mut self,
        camera: &Camera,
        batches: &[PointBatch<'_>],
        opts: &RenderOptions,
    ) -> Result<Frame, RenderError>;
}

/// Which rasterizer [`create`] builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RendererChoice {
    /// wgpu when an adapter exists (hardware preferred, software accepted), else CPU.
    #[default]
    Auto,
    Gpu,
    Cpu,
}

impl std::str::FromStr for RendererChoice {
    type Err = RenderError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "gpu" | "wgpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            other => Err(RenderError::InvalidOptions(format!(
                "unknown renderer '{other}', expected auto, gpu or cpu"
            ))),
        }
    }
}

/// Builds a rasterizer (Auto: a hardware GPU adapter, else the CPU). `Gpu` fails with [`RenderError::NoAdapter`] when no
/// adapter can be created; `Auto` then falls back to the CPU. Check
/// [`Rasterizer::name`] for what was chosen.
///
/// Note that `Auto` accepts software adapters: on a 2-core machine lavapipe
/// rasterized ~3x slower than [`cpu::CpuRasterizer`] (see benches/render.rs),
/// so callers that know they run without a hardware GPU may prefer `Cpu`.
pub fn create(choice: RendererChoice) -> Result<Box<dyn Rasterizer>, RenderError> {
    match choice {
        RendererChoice::Cpu => Ok(Box::new(cpu::CpuRasterizer::new())),
        RendererChoice::Gpu => Ok(Box::new(gpu::GpuRasterizer::new()?)),
        // A software adapter (lavapipe, llvmpipe) is about 3x slower than the CPU
        // rasterizer on the same cores (measured: 86 vs 291 M points/s on 2 cores),
        // so Auto takes the GPU only when it is real hardware.
        RendererChoice::Auto => match gpu::GpuRasterizer::new() {
            Ok(g) if g.adapter_info().device_type != wgpu::DeviceType::Cpu => Ok(Box::new(g)),
            _ => Ok(Box::new(cpu::CpuRasterizer::new())),
        },
    }
}

/// Validates all batches and returns the total number of points.
pub(crate) fn total_points(batches: &[PointBatch<'_>]) -> Result<usize, RenderError> {
    let mut n = 0usize;
    for b in batches {
        n += b.checked_len()?;
    }
    Ok(n)
}
