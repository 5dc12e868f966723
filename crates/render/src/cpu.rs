//! The CPU rasterizer: rayon workers transform points with the `f32` MVP of their
//! batch, clip, project and splat `depth << 32 | colour` values into a 64-bit
//! framebuffer with a minimum (nearest wins, ties to the smaller colour), then a
//! parallel pass merges and resolves to RGBA8 (plus linear depth for eye-dome
//! lighting).
//!
//! Two strategies are implemented ([`CpuStrategy`]): one private framebuffer per
//! worker thread merged at the end (default, faster on 2 cores: no atomics, no
//! cache-line ping-pong), or one shared framebuffer updated with a
//! compare-exchange minimum. Input order is kept: each worker takes contiguous
//! chunks, so spatially ordered (Morton/Hilbert) input touches few cache lines.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use glam::Mat4;
use rayon::prelude::*;

use super::{
    Camera, EMPTY_PIXEL, Frame, FrameStats, PointBatch, Rasterizer, RenderError, RenderOptions,
    edl, total_points,
};

/// Points per work item: large enough to amortize scheduling, small enough to
/// balance two threads when parts of the input are culled.
const CHUNK: usize = 1 << 16;

/// Points per transform block in [`Projector::splat`].
const LANES: usize = 64;

/// Rows per block in the merge/resolve pass.
const MERGE_ROWS: usize = 16;

/// Most memory the per-thread framebuffers may take together; beyond it (many
/// threads, huge frames) the shared atomic framebuffer is used instead.
const PER_THREAD_BUDGET: usize = 1 << 30;

/// How worker threads share the framebuffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CpuStrategy {
    /// One framebuffer per worker thread, merged with `min` at the end.
    #[default]
    PerThread,
    /// One framebuffer shared by all workers, compare-exchange minimum.
    SharedAtomic,
}

/// The CPU rasterizer; keeps its framebuffers between frames.
pub struct CpuRasterizer {
    strategy: CpuStrategy,
    size: (u32, u32),
    per_thread: Vec<Mutex<Vec<u64>>>,
    shared: Vec<AtomicU64>,
    depth: Vec<f32>,
    /// Whether [`Rasterizer::last_ids`] is filled (a second projection pass).
    keep_ids: bool,
    /// Per pixel of the last frame, the point that won it (see [`super::pick::point_id`]).
    ids: Vec<u64>,
}

impl Default for CpuRasterizer {
    fn default() -> Self {
        Self::new()
    }
}

/// The per-batch transform: MVP columns and viewport constants.
#[derive(Clone, Copy)]
pub(crate) struct Projector {
    m: Mat4,
    hw: f32,
    hh: f32,
    w: i32,
    h: i32,
    size: i32,
    /// `(size - 1) / 2`: offset from the projected centre to the first covered pixel centre.
    off: f32,
}

impl Projector {
    pub(crate) fn new(m: Mat4, width: u32, height: u32, size: u32) -> Projector {
        Projector {
            m,
            hw: width as f32 * 0.5,
            hh: height as f32 * 0.5,
            w: width as i32,
            h: height as i32,
            size: size as i32,
            off: (size as f32 - 1.0) * 0.5,
        }
    }

    /// Splats points `[start, end)` of `b` through `put(pixel_index, packed,
    /// point_index)` (the index of the point in `b`; the rasterizer ignores it,
    /// picking keeps it).
    ///
    /// Two phases per block of [`LANES`] points: a branch-free transform that
    /// the compiler vectorizes (first covered pixel, depth bits, validity),
    /// then the scalar scatter.
    #[inline(always)]
    pub(crate) fn splat<F: FnMut(usize, u64, usize)>(
        &self,
        b: &PointBatch<'_>,
        start: usize,
        end: usize,
        mut put: F,
    ) {
        let m = &self.m;
        let (hw, hh, wi, hi) = (self.hw, self.hh, self.w, self.h);
        let (wf, hf) = (hw * 2.0, hh * 2.0);
        let wu = wi as usize;
        let size = self.size;
        let off = self.off;
        // A splat starting at floor(f) covers floor(f)..floor(f) + size - 1, so it
        // is visible when f >= 1 - size (and f < frame side).
        let lo = (1 - size) as f32;
        let mut px = [0i32; LANES];
        let mut py = [0i32; LANES];
        let mut dep = [0u32; LANES];
        let mut ok = [0u8; LANES];
        let mut s = start;
        while s < end {
            let e = (s + LANES).min(end);
            let n = e - s;
            let (xs, ys, zs, cs) = (&b.x[s..e], &b.y[s..e], &b.z[s..e], &b.color[s..e]);
            for j in 0..n {
                let (x, y, z) = (xs[j], ys[j], zs[j]);
                let cw = m.x_axis.w * x + m.y_axis.w * y + m.z_axis.w * z + m.w_axis.w;
                let cz = m.x_axis.z * x + m.y_axis.z * y + m.z_axis.z * z + m.w_axis.z;
                let cx = m.x_axis.x * x + m.y_axis.x * y + m.z_axis.x * z + m.w_axis.x;
                let cy = m.x_axis.y * x + m.y_axis.y * y + m.z_axis.y * z + m.w_axis.y;
                let sx = cx / cw * hw + hw;
                let sy = hh - cy / cw * hh;
                let fx = sx - off;
                let fy = sy - off;
                // All comparisons are false for NaN, so NaN is rejected.
                let valid =
                    cw > 0.0 && cz >= 0.0 && cz <= cw && fx >= lo && fy >= lo && fx < wf && fy < hf;
                // Truncation of `v + 8` is floor(v) + 8 for v > -8. Only used
                // when valid (-8 < v < frame side); wrapping keeps garbage
                // lanes (NaN, huge) from overflowing.
                px[j] = ((fx + 8.0) as i32).wrapping_sub(8);
                py[j] = ((fy + 8.0) as i32).wrapping_sub(8);
                dep[j] = cw.to_bits();
                ok[j] = valid as u8;
            }
            if size == 1 {
                for j in 0..n {
                    if ok[j] != 0 {
                        let (x, y) = (px[j].clamp(0, wi - 1), py[j].clamp(0, hi - 1));
                        let v = ((dep[j] as u64) << 32) | (cs[j] & 0x00ff_ffff) as u64;
                        put(y as usize * wu + x as usize, v, s + j);
                    }
                }
            } else {
                for j in 0..n {
                    if ok[j] == 0 {
                        continue;
                    }
                    let v = ((dep[j] as u64) << 32) | (cs[j] & 0x00ff_ffff) as u64;
                    let (x0, y0) = (px[j], py[j]);
                    for y in y0.max(0)..(y0 + size).min(hi) {
                        let row = y as usize * wu;
                        for x in x0.max(0)..(x0 + size).min(wi) {
                            put(row + x as usize, v, s + j);
                        }
                    }
                }
            }
            s = e;
        }
    }
}

impl CpuRasterizer {
    pub fn new() -> CpuRasterizer {
        Self::with_strategy(CpuStrategy::default())
    }

    pub fn with_strategy(strategy: CpuStrategy) -> CpuRasterizer {
        CpuRasterizer {
            strategy,
            size: (0, 0),
            per_thread: Vec::new(),
            shared: Vec::new(),
            depth: Vec::new(),
            keep_ids: false,
            ids: Vec::new(),
        }
    }

    pub fn strategy(&self) -> CpuStrategy {
        self.strategy
    }

    /// Linear view depth of the last frame (`INFINITY` for background), row-major.
    pub fn last_depth(&self) -> &[f32] {
        &self.depth
    }

    /// (Re)allocates framebuffers for `width`×`height`; they are kept cleared
    /// (all [`EMPTY_PIXEL`]) between frames by the resolve pass.
    fn prepare(&mut self, width: u32, height: u32) -> CpuStrategy {
        let n = width as usize * height as usize;
        let threads = rayon::current_num_threads().max(1);
        if self.size != (width, height) {
            self.per_thread.clear();
            self.shared = Vec::new();
            self.size = (width, height);
        }
        let strategy = match self.strategy {
            CpuStrategy::PerThread if threads * n * 8 > PER_THREAD_BUDGET => {
                self.per_thread.clear();
                CpuStrategy::SharedAtomic
            }
            s => s,
        };
        match strategy {
            CpuStrategy::PerThread => {
                if self.per_thread.len() != threads {
                    self.per_thread = (0..threads)
                        .map(|_| Mutex::new(vec![EMPTY_PIXEL; n]))
                        .collect();
                }
            }
            CpuStrategy::SharedAtomic => {
                if self.shared.len() != n {
                    self.shared = (0..n).map(|_| AtomicU64::new(EMPTY_PIXEL)).collect();
                }
            }
        }
        strategy
    }
}

/// Work items: (batch index, start, end), in input order.
fn work_items(batches: &[PointBatch<'_>]) -> Vec<(usize, usize, usize)> {
    let mut items = Vec::new();
    for (bi, b) in batches.iter().enumerate() {
        let n = b.len();
        let mut s = 0;
        while s < n {
            let e = (s + CHUNK).min(n);
            items.push((bi, s, e));
            s = e;
        }
    }
    items
}

/// Writes the resolved colour of packed value `v` to `out` and its depth to `d`.
#[inline(always)]
fn resolve_px(v: u64, bg: [u8; 3], out: &mut [u8], d: &mut f32) {
    if v == EMPTY_PIXEL {
        out.copy_from_slice(&[bg[0], bg[1], bg[2], 255]);
        *d = f32::INFINITY;
    } else {
        let c = v as u32;
        out.copy_from_slice(&[c as u8, (c >> 8) as u8, (c >> 16) as u8, 255]);
        *d = f32::from_bits((v >> 32) as u32);
    }
}

/// The id pass: per pixel, the smallest [`super::pick::point_id`] among the
/// points whose packed value is the one the frame resolved there (read back
/// from its colour and depth before eye-dome lighting), so the id is the point
/// the image shows, ties broken like the frame's minimum. Runs only when ids
/// are asked for: the frame path itself is unchanged.
fn winners(
    projs: &[Projector],
    batches: &[PointBatch<'_>],
    items: &[(usize, usize, usize)],
    rgba: &[u8],
    depth: &[f32],
) -> Vec<u64> {
    let ids: Vec<AtomicU64> = (0..depth.len())
        .map(|_| AtomicU64::new(super::pick::NO_POINT))
        .collect();
    items.par_iter().for_each(|&(bi, s, e)| {
        projs[bi].splat(&batches[bi], s, e, |i, v, j| {
            let d = depth[i];
            if d == f32::INFINITY {
                return;
            }
            let c = u32::from_le_bytes([rgba[i * 4], rgba[i * 4 + 1], rgba[i * 4 + 2], 0]);
            if v == ((d.to_bits() as u64) << 32 | c as u64) {
                ids[i].fetch_min(super::pick::point_id(bi, j), Ordering::Relaxed);
            }
        });
    });
    ids.into_iter().map(AtomicU64::into_inner).collect()
}

impl Rasterizer for CpuRasterizer {
    fn keep_ids(&mut self, on: bool) -> bool {
        self.keep_ids = on;
        true
    }

    fn last_ids(&self) -> Option<&[u64]> {
        (self.keep_ids && !self.ids.is_empty()).then_some(self.ids.as_slice())
    }

    fn name(&self) -> String {
        let t = rayon::current_num_threads();
        let s = if t == 1 { "" } else { "s" };
        match self.strategy {
            CpuStrategy::PerThread => format!("cpu ({t} thread{s})"),
            CpuStrategy::SharedAtomic => format!("cpu ({t} thread{s}, shared atomic framebuffer)"),
        }
    }

    fn render(
        &mut self,
        camera: &Camera,
        batches: &[PointBatch<'_>],
        opts: &RenderOptions,
    ) -> Result<Frame, RenderError> {
        let point_size = opts.validate()?;
        let total = total_points(batches)?;
        let t0 = Instant::now();
        let (w, h) = (opts.width, opts.height);
        let npx = w as usize * h as usize;
        let strategy = self.prepare(w, h);
        let aspect = opts.aspect();
        let projs: Vec<Projector> = batches
            .iter()
            .map(|b| Projector::new(camera.view_proj_aspect(b.origin, aspect), w, h, point_size))
            .collect();
        let items = work_items(batches);
        let mut rgba = vec![0u8; npx * 4];
        self.depth.resize(npx, f32::INFINITY);
        let bg = opts.background;
        let row = w as usize;
        let block = MERGE_ROWS * row;

        match strategy {
            CpuStrategy::PerThread => {
                let bufs = &self.per_thread;
                let nb = bufs.len();
                items.par_iter().for_each(|&(bi, s, e)| {
                    let t = rayon::current_thread_index().unwrap_or(0) % nb;
                    // Uncontended unless called from outside the pool.
                    let mut guard = match bufs[t].lock() {
                        Ok(g) => g,
                        Err(p) => p.into_inner(),
                    };
                    let buf = guard.as_mut_slice();
                    projs[bi].splat(&batches[bi], s, e, |i, v, _| {
                        // Branch-free: ordered input makes `v < *p` unpredictable.
                        if let Some(p) = buf.get_mut(i) {
                            *p = (*p).min(v);
                        }
                    });
                });
                // Merge: per row block, min over all thread buffers, reset them, resolve.
                let mut owned: Vec<Vec<u64>> = self
                    .per_thread
                    .iter_mut()
                    .map(|m| match m.get_mut() {
                        Ok(v) => std::mem::take(v),
                        Err(p) => std::mem::take(p.into_inner()),
                    })
                    .collect();
                let nblocks = npx.div_ceil(block);
                let mut blocks: Vec<Vec<&mut [u64]>> = (0..nblocks)
                    .map(|_| Vec::with_capacity(owned.len()))
                    .collect();
                for b in owned.iter_mut() {
                    for (i, c) in b.chunks_mut(block).enumerate() {
                        blocks[i].push(c);
                    }
                }
                blocks
                    .into_par_iter()
                    .zip(rgba.par_chunks_mut(block * 4))
                    .zip(self.depth.par_chunks_mut(block))
                    .for_each(|((mut parts, out), dep)| {
                        let Some((first, rest)) = parts.split_first_mut() else {
                            return;
                        };
                        for j in 0..first.len() {
                            let mut v = first[j];
                            first[j] = EMPTY_PIXEL;
                            for r in rest.iter_mut() {
                                v = v.min(r[j]);
                                r[j] = EMPTY_PIXEL;
                            }
                            resolve_px(v, bg, &mut out[j * 4..j * 4 + 4], &mut dep[j]);
                        }
                    });
                for (m, v) in self.per_thread.iter_mut().zip(owned) {
                    match m.get_mut() {
                        Ok(slot) => *slot = v,
                        Err(p) => *p.into_inner() = v,
                    }
                }
            }
            CpuStrategy::SharedAtomic => {
                let buf = &self.shared;
                items.par_iter().for_each(|&(bi, s, e)| {
                    projs[bi].splat(&batches[bi], s, e, |i, v, _| {
                        let a = &buf[i];
                        let mut cur = a.load(Ordering::Relaxed);
                        while v < cur {
                            match a.compare_exchange_weak(
                                cur,
                                v,
                                Ordering::Relaxed,
                                Ordering::Relaxed,
                            ) {
                                Ok(_) => break,
                                Err(x) => cur = x,
                            }
                        }
                    });
                });
                buf.par_chunks(block)
                    .zip(rgba.par_chunks_mut(block * 4))
                    .zip(self.depth.par_chunks_mut(block))
                    .for_each(|((px, out), dep)| {
                        for (j, a) in px.iter().enumerate() {
                            let v = a.swap(EMPTY_PIXEL, Ordering::Relaxed);
                            resolve_px(v, bg, &mut out[j * 4..j * 4 + 4], &mut dep[j]);
                        }
                    });
            }
        }
        self.ids.clear();
        if self.keep_ids {
            self.ids = winners(&projs, batches, &items, &rgba, &self.depth);
        }
        if opts.eye_dome_lighting {
            edl::apply(&mut rgba, &self.depth, w, h, &opts.edl);
        }
        Ok(Frame {
            width: w,
            height: h,
            rgba,
            stats: FrameStats {
                points_drawn: total as u64,
                render_ms: t0.elapsed().as_secs_f64() * 1e3,
                upload_ms: 0.0,
            },
        })
    }
}
